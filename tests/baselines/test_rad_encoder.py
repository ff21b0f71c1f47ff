"""RAD-Embeddings' cDFA graph and GATv2 encoder: graph construction on a hand-built DFA, the
encoder against a per-node numpy transcription, and embeddings that depend on the language only
(state renumbering, node order, conjunct order, padding, advancing = minimising the residual)."""

import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import automata
from specrl_jax.automata import rad_sampler as rad
from specrl_jax.baselines.rad import encoder as enc

ALPHABET = automata.all_subsets(2)  # symbols {}, a, b, ab
# a leads on, b fails; then b fails and ab accepts
HAND = rad.DFA(np.array([[0, 1, 3, 0], [1, 1, 3, 2], [2, 2, 2, 2], [3, 3, 3, 3]]),
               np.array([0, 0, 1, 0], bool), 0)
EVENTUALLY_B = rad.DFA(np.array([[0, 0, 1, 1], [1, 1, 1, 1]]), np.array([0, 1], bool), 0)


CAPS = {"max_conjuncts": 2, "max_states": 5, "num_state_nodes": 8, "num_transition_nodes": 8,
        "max_in": 3}
GRAPH_CAPS = ("num_state_nodes", "num_transition_nodes", "max_in")


def _graph(cdfas, index=0, q=None, **caps):
    """The graph of conjunction `index` at states `q`, padded to `caps` (default `CAPS`, one
    shape for every graph here, so the encoder compiles once)."""
    caps = {**CAPS, **caps}
    bank = rad.build_bank(cdfas, ALPHABET, **{k: v for k, v in caps.items()
                                              if k in ("max_conjuncts", "max_states")})
    graphs = enc.build_graphs(bank, **{k: v for k, v in caps.items() if k in GRAPH_CAPS})
    q = np.zeros(bank.max_conjuncts, np.int32) if q is None else np.asarray(q, np.int32)
    q = jnp.asarray(np.pad(q, (0, bank.max_conjuncts - q.size)))  # unused conjuncts: state 0
    return enc.graph_of(graphs, bank, index, q)


def _edges(g):
    """(sender, receiver) of every live edge but the self edges (slot 0)."""
    g = jax.tree.map(np.asarray, g)
    return [(int(g.neighbours[i, d]), i) for i in range(g.neighbours.shape[0])
            for d in range(1, g.neighbours.shape[1]) if g.neighbour_mask[i, d]]


def _encoder():
    encoder = enc.RADEncoder()
    params = encoder.init(jax.random.key(0), _graph([[HAND]]))
    return jax.jit(encoder.apply), params


def test_graph_of_a_hand_built_dfa():
    g = jax.tree.map(np.asarray, _graph([[HAND]]))
    feats = g.features
    # AND, 4 states (canonical: 0 start, 1 after a, 2 fail, 3 accept), 4 transition nodes
    assert g.node_mask.sum() == 9 and feats.shape == (16, 4 + 6)
    # every live node attends to itself (slot 0), padding and masked nodes to nothing
    assert np.array_equal(g.neighbour_mask[:, 0], g.node_mask)
    assert np.array_equal(g.neighbours[:, 0], np.arange(16))
    assert feats[0, enc.AND] == 1 and feats[:, enc.AND].sum() == 1
    states = np.flatnonzero(feats[:, enc.NORMAL])
    assert len(states) == 4 and feats[states[0], enc.INIT] == 1 and feats[:, enc.INIT].sum() == 1
    assert feats[states, enc.ACCEPTING].tolist() == [0, 0, 0, 1]
    assert feats[states, enc.REJECTING].tolist() == [0, 0, 1, 0]
    temps = np.flatnonzero(feats[:, enc.TEMP])
    symbol_sets = {tuple(feats[t, :4].astype(int)) for t in temps}
    assert symbol_sets == {(0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1)}  # a; b (twice); ab
    edges = set(_edges(g))
    # each transition s -> e: edge e -> temp and temp -> s; one AND edge from the start state
    for t in temps:
        into = [s for s, r in edges if r == t]
        out = [r for s, r in edges if s == t]
        assert len(into) == 1 and len(out) == 1 and out[0] != into[0]
    assert (states[0], 0) in edges and sum(r == 0 for _, r in edges) == 1
    assert len(edges) == 2 * 4 + 1
    # advanced by a: the start and its transitions are gone, state 1 is current
    g1 = jax.tree.map(np.asarray, _graph([[HAND]], q=[1]))
    assert g1.node_mask.sum() == 1 + 3 + 2
    assert g1.features[states[1], enc.INIT] == 1 and not g1.node_mask[states[0]]


def _numpy_encoder(params, g):
    """The encoder written out per node with dense loops (one graph)."""
    p = jax.tree.map(lambda x: np.asarray(x, np.float64), params["params"])
    live = np.flatnonzero(g.node_mask)
    edges = _edges(g) + [(i, i) for i in live]
    h0 = np.asarray(g.features, np.float64) @ p["embed"]["kernel"] + p["embed"]["bias"]
    h = h0.copy()
    gat = p["gat"]
    for _ in range(8):
        x = np.concatenate([h, h0], axis=1)
        both = x @ gat["kernel"] + gat["bias"]  # W_src and W_dst side by side
        src = both[:, :256].reshape(len(x), 4, 64)
        dst = both[:, 256:].reshape(len(x), 4, 64)
        new = np.zeros_like(h)
        for i in live:
            senders = [s for s, r in edges if r == i]
            z = src[senders] + dst[i][None]
            score = (np.where(z > 0, z, 0.2 * z) * gat["attention"][None]).sum(-1)  # [n, 4]
            alpha = np.exp(score - score.max(0)) / np.exp(score - score.max(0)).sum(0)
            new[i] = np.tanh((alpha[..., None] * src[senders]).sum(0)).sum(0)
        h = new
    return h[0] @ p["readout"]["kernel"] + p["readout"]["bias"]


def test_encoder_matches_a_per_node_numpy_transcription():
    encoder, params = _encoder()
    for cdfa, q in (([HAND], [1]), ([HAND, EVENTUALLY_B], [0, 0])):
        g = _graph([cdfa], q=q)
        got = encoder(params, g)
        want = _numpy_encoder(params, jax.tree.map(np.asarray, g))
        np.testing.assert_allclose(got, want, rtol=2e-4, atol=2e-4)


def test_embedding_depends_on_the_language_only():
    encoder, params = _encoder()
    emb = lambda g: np.asarray(encoder(params, g))
    base = emb(_graph([[HAND, EVENTUALLY_B]]))
    # a non-minimal, renumbered DFA of HAND's language: duplicate state 1, shuffle the numbers
    big = rad.DFA(np.array([[0, 4, 3, 0], [1, 1, 3, 2], [2, 2, 2, 2], [3, 3, 3, 3],
                            [1, 4, 3, 2]]), np.array([0, 0, 1, 0, 0], bool), 0)
    perm = np.array([3, 0, 4, 1, 2])
    inv = np.argsort(perm)
    renamed = rad.DFA(perm[big.delta[inv]], big.accepting[inv], int(perm[0]))
    np.testing.assert_allclose(emb(_graph([[renamed, EVENTUALLY_B]])), base, atol=1e-5)
    # conjunct order and padding do not matter
    np.testing.assert_allclose(emb(_graph([[EVENTUALLY_B, HAND]])), base, atol=1e-5)
    padded = _graph([[HAND, EVENTUALLY_B]], max_conjuncts=3, max_states=7, num_state_nodes=10,
                    num_transition_nodes=9, max_in=4)
    np.testing.assert_allclose(emb(padded), base, atol=1e-5)
    # node order (AND stays node 0, each block keeps its nodes) and slot order do not matter
    g = jax.tree.map(np.asarray, _graph([[HAND, EVENTUALLY_B]]))
    rng = np.random.default_rng(0)
    ns = CAPS["num_state_nodes"]
    nt = g.node_mask.shape[0] - ns
    order = np.r_[0, 1 + rng.permutation(ns - 1), ns + rng.permutation(nt)]  # new -> old
    where = np.argsort(order)  # old -> new
    slots = np.r_[0, 1 + rng.permutation(g.neighbours.shape[1] - 1)]
    shuffled = enc.Graph(g.features[order], g.node_mask[order],
                         where[g.neighbours[order]][:, slots], g.neighbour_mask[order][:, slots])
    np.testing.assert_allclose(emb(shuffled), base, atol=1e-5)
    # advancing masks the graph into that of the minimised residual DFA
    residual = rad.minimise(rad.DFA(HAND.delta, HAND.accepting, 1))[0]
    np.testing.assert_allclose(emb(_graph([[HAND]], q=[1])), emb(_graph([[residual]])),
                               atol=1e-5)
    # and the embedding does see the language: other DFAs, other states, other embeddings
    assert np.abs(emb(_graph([[HAND]])) - emb(_graph([[HAND]], q=[1]))).max() > 1e-3
    assert np.abs(emb(_graph([[HAND]])) - base).max() > 1e-3
    # a batch gives each graph's own embedding
    two = jax.tree.map(lambda a, b: jnp.stack([a, b]), _graph([[HAND, EVENTUALLY_B]]),
                       _graph([[HAND, EVENTUALLY_B]], q=[1, 0]))
    batch = emb(two)
    np.testing.assert_allclose(batch[0], base, atol=1e-5)
    np.testing.assert_allclose(batch[1], emb(_graph([[HAND, EVENTUALLY_B]], q=[1, 0])),
                               atol=1e-5)


def test_packed_batches_encode_and_differentiate_as_padded_ones():
    # RAD conjunctions over 4 letters, each advanced by a few random symbols
    bank = rad.sample_bank(48, automata.zero_or_one(4), seed=3, max_size=40)
    graphs = enc.build_graphs(bank)
    rng = np.random.default_rng(0)
    index = jnp.asarray(rng.integers(0, bank.size, 32), jnp.int32)
    symbols = jnp.asarray(rng.integers(0, 5, (2, 32)), jnp.int32)

    @jax.jit
    def advanced_graphs(index, symbols):
        q = jnp.zeros((32, bank.max_conjuncts), jnp.int32)
        for symbol in symbols:
            q = jax.vmap(rad.advance, in_axes=(None, 0, 0, 0))(bank, index, q, symbol)
        return jax.vmap(enc.graph_of, in_axes=(None, None, 0, 0))(graphs, bank, index, q)

    batch = advanced_graphs(index, symbols)
    packing = enc.packing_allowance(graphs, bank)
    tight = tuple(0.2 * a for a in packing)  # too few rows: the batch is encoded padded
    num_graphs, num_nodes, num_slots = batch.neighbours.shape
    for allowance, fit in ((packing, True), (tight, False)):
        sizes = enc.block_sizes(allowance, num_graphs, num_nodes, num_slots)
        assert sizes is not None and sum(sizes) < num_graphs * num_nodes
        rows, fits = jax.jit(enc.pack_rows, static_argnums=1)(batch, sizes)
        assert bool(fits) == fit
    # packed: every live node on one row, in a block wide enough for its in-neighbours
    rows, _ = jax.jit(enc.pack_rows, static_argnums=1)(
        batch, enc.block_sizes(packing, num_graphs, num_nodes, num_slots))
    assert int(rows.row_mask.sum()) == int(batch.node_mask.sum())
    assert sum(int(m.sum()) for m in rows.slot_mask) == int(batch.neighbour_mask[..., 1:].sum())
    np.testing.assert_array_equal(rows.features[rows.roots], batch.features[:, 0])

    def run(module, params):
        def loss(p):
            emb = module.apply(p, batch)
            return jnp.sum(jnp.sin(emb)), emb

        (_, emb), grads = jax.value_and_grad(loss, has_aux=True)(params)
        return emb, grads

    padded = enc.RADEncoder(hidden=8, num_layers=2)
    params = padded.init(jax.random.key(0), batch)
    want_emb, want_grads = jax.jit(lambda p: run(padded, p))(params)
    for allowance in (packing, tight):
        module = enc.RADEncoder(hidden=8, num_layers=2, packing=allowance)
        emb, grads = jax.jit(lambda p, m=module: run(m, p))(params)
        np.testing.assert_allclose(emb, want_emb, rtol=1e-5, atol=1e-5)
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5),
                     grads, want_grads)
