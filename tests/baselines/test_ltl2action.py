"""LTL2Action: the R-GCN formula encoder (against a numpy transcription, node permutations,
edge types), learning a tiny world through the task loop, and the test-time agent's own
progression against the task loop's automaton flags."""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import spot
from tiny_learning import early_late, train_rows

from specrl_jax import automata
from specrl_jax.automata import zero_or_one
from specrl_jax.baselines import ltl2action
from specrl_jax.baselines.encoders import obs_parts
from specrl_jax.envs.letter import LetterConfig, make_letter_world
from specrl_jax.tasks import TaskEnv
from specrl_jax.tasks.progression import (
    EDGE_ARG1,
    EDGE_ARG2,
    build_bank,
    formula_graph,
    num_features,
)

PROPS = tuple("abcdefghijkl")


def _graph(text, pad=12):
    tokens, parent, edge = (np.asarray(x) for x in formula_graph(spot.formula(text), PROPS))
    padding = pad - len(tokens)
    return (np.pad(tokens, (0, padding), constant_values=-1),
            np.pad(parent, (0, padding), constant_values=-1), np.pad(edge, (0, padding)))


def _encoder():
    encoder = ltl2action.networks.RGCNEncoder(num_features(len(PROPS)))
    tokens, parent, edge = _graph("!a U (b & F c)")
    params = encoder.init(jax.random.key(0), tokens, parent, edge)
    return encoder, params


def _numpy_rgcn(params, tokens, parent, edge, features, layers=8):
    """The R-GCN of LTL2Action written out per node: h_i <- tanh(W_0 x_i + sum over children
    j of W_{type(j)} x_j + b), x = [h, h0]; readout at the root."""
    p = jax.tree.map(np.asarray, params["params"])
    live = [i for i in range(len(tokens)) if tokens[i] >= 0]
    onehot = np.eye(features)[tokens[live]]
    h0 = {i: row for i, row in zip(live, onehot @ p["Dense_0"]["kernel"] + p["Dense_0"]["bias"])}
    h = dict(h0)
    weight, bias = p["relation_kernel"], p["relation_bias"]
    for _ in range(layers):
        x = {i: np.concatenate([h[i], h0[i]]) for i in live}
        h = {i: np.tanh(x[i] @ weight[0]
                        + sum(x[j] @ weight[edge[j]] for j in live if parent[j] == i) + bias)
             for i in live}
    root = next(i for i in live if parent[i] < 0)
    return h[root] @ p["Dense_1"]["kernel"] + p["Dense_1"]["bias"]


def test_rgcn_matches_a_per_node_numpy_transcription():
    encoder, params = _encoder()
    for text in ("!a U (b & F c)", "F(a & F(b | c))", "G !d & F e"):
        tokens, parent, edge = _graph(text)
        got = encoder.apply(params, tokens, parent, edge)
        want = _numpy_rgcn(params, tokens, parent, edge, num_features(len(PROPS)))
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)


def test_rgcn_relation_weights_start_as_dgl_043_relgraphconv():
    """DGL 0.4.3: `xavier_uniform_(weight[4, 64, 32], gain=calculate_gain('relu'))`; PyTorch's
    fans of a 3-D tensor are fan_in = 64 * 32, fan_out = 4 * 32, so the bound is
    sqrt(2) * sqrt(6 / 2176) = 0.07426 (flax's fan_avg convention would give 0.177)."""
    _, params = _encoder()
    weight = np.asarray(params["params"]["relation_kernel"])
    bound = 0.074261
    assert weight.shape == (4, 64, 32)
    assert 0.99 * bound < np.abs(weight).max() <= bound
    np.testing.assert_allclose(weight.std(), bound / np.sqrt(3), rtol=0.03)
    np.testing.assert_array_equal(np.asarray(params["params"]["relation_bias"]), 0.0)


def test_rgcn_is_invariant_to_node_order_and_padding_but_not_to_edge_types():
    encoder, params = _encoder()
    tokens, parent, edge = _graph("!a U (b & F c)")
    base = np.asarray(encoder.apply(params, tokens, parent, edge))
    rng = np.random.default_rng(0)
    for _ in range(3):
        order = rng.permutation(len(tokens))  # new position -> old node (padding moves too)
        where = np.argsort(order)  # old node -> new position
        new_parent = np.where(parent[order] >= 0, where[np.maximum(parent[order], 0)], -1)
        got = encoder.apply(params, tokens[order], new_parent, edge[order])
        np.testing.assert_allclose(got, base, rtol=1e-5, atol=1e-5)
    padded = encoder.apply(params, *(np.pad(x, (0, 7), constant_values=-1 if i < 2 else 0)
                                      for i, x in enumerate((tokens, parent, edge))))
    np.testing.assert_allclose(padded, base, rtol=1e-5, atol=1e-5)
    swapped = edge.copy()  # the until's operands exchanged: !a U X becomes X U !a
    swapped[(parent == 0) & (edge == EDGE_ARG1)] = EDGE_ARG2
    swapped[(parent == 0) & (edge == EDGE_ARG2)] = EDGE_ARG1
    swapped_emb = np.asarray(encoder.apply(params, tokens, parent, swapped))
    assert np.abs(swapped_emb - base).max() > 1e-3
    # a batch of graphs gives each graph's own embedding
    other = _graph("F(a & F(b | c))")
    pairs = zip((tokens, parent, edge), other)
    batch = encoder.apply(params, *(np.stack([x, y]) for x, y in pairs))
    np.testing.assert_allclose(batch[0], base, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(batch[1], encoder.apply(params, *other), rtol=1e-5, atol=1e-5)


def _small_bank_obs(batch_shape):
    """A bank of a few formulas over 3 propositions (S states) and `FormulaObs` of random states
    in it (no world observation) for the bootcamp network, which reads the formula alone."""
    props = ("a", "b", "c")
    bank = build_bank(["!a U (b & F c)", "F(a & F b)", "G !c & F a"], props, zero_or_one(3))
    graphs = ltl2action.FormulaGraphs(bank)
    rng = np.random.default_rng(0)
    state = jnp.asarray(rng.integers(0, graphs.num_states, batch_shape), jnp.int32)
    network = ltl2action.pretrain.BootcampNetwork(props, 3)
    return network, ltl2action.FormulaObs({}, state, graphs)


def test_rgcn_table_of_the_bank_equals_each_samples_own_graph_in_outputs_and_gradients():
    """Enough samples: the R-GCN runs once over the bank's merged subtrees and is gathered by
    state; vmapped over the samples (one each), it runs over each sample's tree. Both give the
    same logits, values and parameter gradients, alone and vmapped over two seeds."""
    network, obs = _small_bank_obs((2, 3, 8))
    assert obs.graphs.num_states < 24
    params = jax.vmap(network.init, in_axes=(0, None))(jax.random.split(jax.random.key(0), 2),
                                                     jax.tree.map(lambda x: x[0, 0], obs))

    def table(p, o):
        out = network.apply(p, o)
        return out.pi.logits, out.value

    def per_sample(p, o):
        return jax.vmap(jax.vmap(lambda one: table(p, one)))(o)

    def outputs_and_grads(embed):
        def loss(p, o):
            return sum(jnp.sum(jnp.sin(x)) for x in embed(p, o))

        return jax.jit(lambda p, o: (embed(p, o), jax.grad(loss)(p, o)))

    first_seed = jax.tree.map(lambda leaf: leaf[0], (params, obs))
    for seeds in (lambda f: f(*first_seed), lambda f: jax.vmap(f)(params, obs)):
        got, grads = seeds(outputs_and_grads(table))
        want, want_grads = seeds(outputs_and_grads(per_sample))
        for x, y in zip(got, want):
            np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6)
        for x, y in zip(jax.tree.leaves(grads), jax.tree.leaves(want_grads)):
            np.testing.assert_allclose(x, y, rtol=1e-4, atol=1e-5)


def test_rgcn_runs_over_the_merged_subtrees_only_when_they_are_fewer_nodes():
    """What the R-GCN reads: the bank's distinct subtrees (`FormulaDag`) where they are fewer
    nodes than the forward pass's padded trees (under `vmap`, one slice's), else the samples'
    own trees."""
    network, obs = _small_bank_obs((64,))
    graphs = obs.graphs
    dag_nodes, num_nodes = graphs.dag.tokens.size, graphs.num_nodes
    most_per_sample = dag_nodes // num_nodes  # at most this many samples: their own trees
    assert 1 <= most_per_sample < 4
    params = network.init(jax.random.key(0), obs)
    seen = []

    def record(call, args, kwargs, context):
        if isinstance(context.module, ltl2action.networks.RGCNEncoder):
            dag = isinstance(args[0], ltl2action.networks.FormulaDag)
            seen.append("dag" if dag else args[0].shape[:-1])  # trees: their batch shape
        return call(*args, **kwargs)

    def shaped(*shape):
        return jax.tree.map(lambda x: x[:np.prod(shape)].reshape(shape), obs)

    with nn.intercept_methods(record):
        for samples in (most_per_sample, most_per_sample + 1):
            jax.eval_shape(network.apply, params, shaped(1, samples))
        for slices in (64 // most_per_sample, 2):  # few and many samples per slice
            jax.eval_shape(jax.vmap(network.apply, in_axes=(None, 0)), params,
                           shaped(slices, 64 // slices))
    assert seen == [(1, most_per_sample), "dag", (most_per_sample,), "dag"]


def test_merged_subtrees_give_each_trees_embedding():
    """`formula_dag` merges the subtrees that formulas share (here `!green U blue` and its
    parts), and the R-GCN over the merged nodes gives every state the embedding of its own
    tree, written out per node."""
    props = ("blue", "green", "magenta", "yellow")
    bank = build_bank(["!(green | yellow) U (magenta & (!green U blue))", "!green U blue",
                       "F (magenta & (!green U blue))", "G F blue & G !green"], props,
                      zero_or_one(4))
    graphs = ltl2action.FormulaGraphs(bank)
    tokens, parent, edge = (np.asarray(x) for x in graphs.tree)
    assert graphs.dag.tokens.size < int((tokens >= 0).sum())
    assert graphs.dag.roots.shape == (graphs.num_states,)
    encoder = ltl2action.networks.RGCNEncoder(num_features(len(props)))
    params = encoder.init(jax.random.key(1), tokens[:1], parent[:1], edge[:1])
    merged = np.asarray(encoder.apply(params, graphs.dag))
    for s in range(graphs.num_states):
        np.testing.assert_allclose(
            merged[s], _numpy_rgcn(params, tokens[s], parent[s], edge[s], num_features(4)),
            rtol=1e-4, atol=1e-5)
    # a tree without nodes reads out zeros through the last Dense layer, as its padded form
    empty = [np.concatenate([x, np.full((1, x.shape[1]), -1 if x is not edge else 0, x.dtype)])
             for x in (tokens, parent, edge)]
    with_empty = ltl2action.networks.formula_dag(*empty)
    assert with_empty.roots[-1] == -1
    with pytest.raises(ValueError, match="each after its parent"):
        ltl2action.networks.formula_dag(tokens[:1, ::-1], parent[:1], edge[:1])
    np.testing.assert_allclose(encoder.apply(params, with_empty),
                               encoder.apply(params, *empty), rtol=1e-5, atol=1e-6)


def _tiny_world(max_steps=6):
    # 5x5 torus, one 'a' and one 'b': the formula says which letter to reach (and which to avoid)
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b"), counts=1),
                                      max_steps=max_steps)
    return world, world.with_map_bank(jax.random.key(0), params, num_maps=64)


TINY_FORMULAS = ["F a", "F b", "!a U b", "!b U a"]


def test_ltl2action_learns_formulas_on_a_tiny_letter_world_through_the_task_loop():
    world, params = _tiny_world()
    method = ltl2action.make_method(world, params, formulas=TINY_FORMULAS)
    updates = 50
    cfg = ltl2action.ppo_config(num_envs=16, num_steps=24, total_timesteps=16 * 24 * updates,
                                update_epochs=4, num_minibatches=2)
    first, last = early_late(train_rows(ltl2action, method, cfg, updates)[1])
    # from below 0.4 to about 0.6 in 50 updates (0.23 -> 0.60 on XLA:CPU's loop emitters)
    assert first < 0.4 and last > max(0.55, first + 0.3), (first, last)


def test_test_time_agent_progresses_the_evaluated_formula_itself():
    """The agent recognises each evaluated spec's formula, and its carried progression is true
    exactly when the task loop's automaton reports success, false exactly on violation."""
    world, params = _tiny_world(max_steps=30)
    formulas = ["!b U a", "F(a & F b)", "!a U b"]
    compiled = automata.compile_suite(formulas, world.propositions, world.alphabet)
    candidates = ["F a", "F b"] + list(reversed(formulas))
    assert ltl2action.match_formulas(compiled, candidates, world.propositions,
                                     np.asarray(world.alphabet)) == formulas
    network = ltl2action.network_for(world)
    policy = ltl2action.make_policy(network, world.alphabet, world.obs_kinds, formulas=candidates)
    task = TaskEnv(world, compiled)
    bank = build_bank(formulas, world.propositions, world.alphabet)  # same formulas, same order
    obs, _ = task.reset(jax.random.key(3), params, 0)
    first = ltl2action.FormulaObs(obs_parts(obs, world.obs_kinds), jnp.int32(0),
                                  ltl2action.FormulaGraphs(bank))
    net_params = network.init(jax.random.key(0), jax.tree.map(lambda x: x[None], first))

    def episode(key, index):
        key_reset, key_loop = jax.random.split(key)
        obs, state = task.reset(key_reset, params, index)
        carry = policy.init(net_params, obs, state, key_loop)

        def body(loop, t):
            obs, state, carry = loop
            key_policy, key_step = jax.random.split(jax.random.fold_in(key_loop, t))
            action, carry = policy.apply(net_params, obs, state, carry, key_policy)
            obs, state, _, _, _, _ = task.step_task(key_step, state, action, params)
            # the carry as the next step's call will see it
            _, seen = policy.apply(net_params, obs, state, carry, key_policy)
            return (obs, state, carry), (seen.state, state.success, state.violation)

        _, trace = jax.lax.scan(body, (obs, state, carry), jnp.arange(30))
        return trace

    run = jax.jit(jax.vmap(episode, in_axes=(0, None)))
    keys = jax.random.split(jax.random.key(4), 24)
    ended = 0
    for index in range(len(formulas)):
        states, success, violation = (np.asarray(x) for x in run(keys, index))
        np.testing.assert_array_equal(np.asarray(bank.is_true)[states], success)
        np.testing.assert_array_equal(np.asarray(bank.is_false)[states], violation)
        ended += int(success[:, -1].sum() + violation[:, -1].sum())
    assert ended > 0
