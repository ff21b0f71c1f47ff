"""RAD-Embeddings' encoder: the graph of a conjunction of DFAs as padded arrays, and the GATv2
network that embeds it (32-d).

Graph (the original's `DFABuilder`, one layer per DFA): one node per DFA state; for each state s
and each distinct successor e != s one *transition* node whose features are the multi-hot set of
symbols leading from s to e, with edges e -> transition -> s (messages flow from successors to
predecessors; self-loops of the DFA are not drawn); one AND node with an edge from each DFA's
current state; every node attends to itself. Node features: the A symbols, then the flags AND,
init (current state), normal (state node), temp (transition node), accepting, rejecting (a
non-accepting state whose every transition is a self-loop), at indices -6 .. -1 as the original.

Layout: node 0 is the AND node, nodes 1 .. Ns-1 the state nodes, nodes Ns .. Ns+Nt-1 the
transition nodes (each block padded). Edges are stored per receiver, as in-neighbour slots
int32[Nn, D]: slot 0 is the node itself; a state or AND node has up to D-1 in-neighbours, a
transition node one (its successor state). The network gathers each node's slots and takes the
attention softmax over them: the sums of segment ops over an edge list, without a scatter in the
forward pass (XLA's scatter made the encoder 10x slower on a CPU).

Packing (`pack_rows`, for batches of many graphs: pretraining). A padded batch is mostly padding:
the Letter bank's graphs have 15 live nodes of 45 on average at their start state (fewer once
advanced) and 2 live slots of 6 per node. The encoder then takes the live nodes of the whole
batch as rows of one array, in blocks by the number of their in-neighbours (0, 1, 2, more), each
block gathering only as many slots as its nodes need; the rows per block are sized for the
batch (`packing_allowance`, from the bank), and a batch that does not fit is encoded padded
(`lax.cond`), so the numbers are the same either way.

The host builds, per conjunction of a bank, the graph of its full minimal DFAs once
(`build_graphs`); inside `jit`, `graph_of` masks the nodes that the current states can no longer
reach, flags the current states and draws the AND node's in-edges, so the graph is that of the
advanced, minimised conjunction (see `automata.rad_sampler`).

Encoder (the original's `GATv2Conv` entry): `h0 = W x`; 8 times one shared GATv2 layer of 4
heads on `[h, h0]` (128 -> 64 per head), tanh per head, heads summed; the AND node's hidden,
through a Dense layer to 32. GATv2: `e_ij = a . LeakyReLU_0.2(W_s x_j + W_d x_i)`, softmax over
the in-edges of i (itself included), `h_i = sum_j alpha_ij W_s x_j`.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.automata.rad_sampler import DFABank
from specrl_jax.baselines.ppo.networks import unit_columns

NUM_FLAGS = 6
AND, INIT, NORMAL, TEMP, ACCEPTING, REJECTING = range(-6, 0)
KIND_PAD, KIND_AND, KIND_STATE, KIND_TRANSITION = 0, 1, 2, 3


def num_features(num_symbols: int) -> int:
    """Node feature width for an alphabet of `num_symbols` symbols."""
    return num_symbols + NUM_FLAGS


@struct.dataclass
class GraphBank:
    """The graphs of a `DFABank`'s conjunctions: K graphs of Nn = Ns + Nt nodes.

    Attributes:
        features: bool[K, Nn, F] node features without the init flag (F = A + 6).
        kind: int8[K, Nn] pad / AND / state / transition node.
        conjunct: int8[K, Nn] the node's DFA (-1: AND or padding).
        state: int8[K, Nn] a state node's state, a transition node's source state.
        state_node: int16[K, N, S] node of each DFA state (-1 none).
        in_transitions: int16[K, Ns, D - 1] the transition nodes sending to each state node
            (-1 padding; the AND node's row is empty: its senders depend on the current states).
        successor: int16[K, Nt] each transition node's successor state node (-1 padding).
    """

    features: jax.Array
    kind: jax.Array
    conjunct: jax.Array
    state: jax.Array
    state_node: jax.Array
    in_transitions: jax.Array
    successor: jax.Array

    @property
    def num_nodes(self) -> int:
        return int(self.kind.shape[-1])


class Graph(NamedTuple):
    """One graph (leading batch axes allowed): `features` float32[Nn, F], `node_mask` bool[Nn],
    and each node's in-neighbour slots `neighbours` int32[Nn, D] (slot 0: the node itself) with
    `neighbour_mask` bool[Nn, D]. Node 0 is the AND node."""

    features: jax.Array
    node_mask: jax.Array
    neighbours: jax.Array
    neighbour_mask: jax.Array


def _cdfa_graph(delta: np.ndarray, accepting: np.ndarray, num_states: np.ndarray) -> dict:
    """Nodes and edges of one conjunction's full DFAs (lists; transition node ids relative to
    the transition block)."""
    num_symbols = delta.shape[-1]
    width = num_features(num_symbols)
    state_feats, state_conj, state_id = [], [], []
    trans_feats, trans_conj, trans_src, successor = [], [], [], []
    state_node = -np.ones(delta.shape[:2], np.int64)
    for n in range(delta.shape[0]):
        for s in range(num_states[n]):
            row = np.zeros(width, bool)
            row[NORMAL] = True
            row[ACCEPTING] = accepting[n, s]
            row[REJECTING] = (not accepting[n, s]) and bool(np.all(delta[n, s] == s))
            state_node[n, s] = 1 + len(state_feats)
            state_feats.append(row), state_conj.append(n), state_id.append(s)
    incoming: dict[int, list[int]] = {}
    for n in range(delta.shape[0]):
        for s in range(num_states[n]):
            for e in np.unique(delta[n, s]):
                if e == s:
                    continue
                row = np.zeros(width, bool)
                row[:num_symbols] = delta[n, s] == e
                row[TEMP] = True
                incoming.setdefault(int(state_node[n, s]), []).append(len(trans_feats))
                trans_feats.append(row), trans_conj.append(n), trans_src.append(s)
                successor.append(int(state_node[n, e]))
    return {"state_feats": state_feats, "state_conj": state_conj, "state_id": state_id,
            "trans_feats": trans_feats, "trans_conj": trans_conj, "trans_src": trans_src,
            "successor": successor, "state_node": state_node, "incoming": incoming}


def build_graphs(bank: DFABank, num_state_nodes: int | None = None,
                 num_transition_nodes: int | None = None, max_in: int | None = None
                 ) -> GraphBank:
    """The graphs of every conjunction of `bank`, padded to the bank's largest blocks (or to
    Ns = `num_state_nodes` including the AND node, Nt = `num_transition_nodes`, and `max_in`
    in-neighbours of a state node)."""
    delta, accepting = np.asarray(bank.delta), np.asarray(bank.accepting)
    num_states = np.asarray(bank.num_states)
    graphs = [_cdfa_graph(delta[k], accepting[k], num_states[k]) for k in range(bank.size)]
    ns = 1 + max(len(g["state_feats"]) for g in graphs)
    nt = max(max(len(g["trans_feats"]) for g in graphs), 1)
    deg = max([len(v) for g in graphs for v in g["incoming"].values()] + [1])
    ns = ns if num_state_nodes is None else num_state_nodes
    nt = nt if num_transition_nodes is None else num_transition_nodes
    deg = deg if max_in is None else max_in
    if any(1 + len(g["state_feats"]) > ns or len(g["trans_feats"]) > nt
           or any(len(v) > deg for v in g["incoming"].values()) for g in graphs):
        raise ValueError(f"a conjunction's graph exceeds num_state_nodes={ns}, "
                         f"num_transition_nodes={nt} or max_in={deg}")
    k, width = bank.size, num_features(delta.shape[-1])
    out = {
        "features": np.zeros((k, ns + nt, width), bool),
        "kind": np.zeros((k, ns + nt), np.int8),
        "conjunct": -np.ones((k, ns + nt), np.int8),
        "state": np.zeros((k, ns + nt), np.int8),
        "state_node": np.stack([g["state_node"] for g in graphs]).astype(np.int16),
        "in_transitions": -np.ones((k, ns, deg), np.int16),
        "successor": -np.ones((k, nt), np.int16),
    }
    for i, g in enumerate(graphs):
        m, t = len(g["state_feats"]), len(g["trans_feats"])
        out["features"][i, 0, AND] = True
        out["kind"][i, 0] = KIND_AND
        if m:
            out["features"][i, 1:1 + m] = np.stack(g["state_feats"])
            out["kind"][i, 1:1 + m] = KIND_STATE
            out["conjunct"][i, 1:1 + m] = g["state_conj"]
            out["state"][i, 1:1 + m] = g["state_id"]
        if t:
            out["features"][i, ns:ns + t] = np.stack(g["trans_feats"])
            out["kind"][i, ns:ns + t] = KIND_TRANSITION
            out["conjunct"][i, ns:ns + t] = g["trans_conj"]
            out["state"][i, ns:ns + t] = g["trans_src"]
            out["successor"][i, :t] = g["successor"]
        for node, senders in g["incoming"].items():
            out["in_transitions"][i, node, :len(senders)] = ns + np.asarray(senders)
    return GraphBank(**jax.device_put(out))


def graph_of(graphs: GraphBank, bank: DFABank, index: jax.Array, q: jax.Array) -> Graph:
    """The graph of conjunction `index` advanced to states `q` int32[N] (one graph; jittable)."""
    kind, conj = graphs.kind[index], graphs.conjunct[index].astype(jnp.int32)
    state = graphs.state[index].astype(jnp.int32)
    conj_safe = jnp.maximum(conj, 0)
    used = bank.num_states[index, conj_safe] > 0
    reachable = bank.reach[index, conj_safe, q[conj_safe], state]
    node_mask = (kind == KIND_AND) | ((kind > KIND_AND) & used & reachable)
    init = (kind == KIND_STATE) & (state == q[conj_safe])
    features = graphs.features[index].astype(jnp.float32).at[:, INIT].set(init)
    # in-neighbours of the AND node (the current state of each used conjunct), of the state
    # nodes (their transition nodes) and of the transition nodes (their successor state)
    current = graphs.state_node[index, jnp.arange(q.shape[-1]), q].astype(jnp.int32)
    current = jnp.where(bank.num_states[index] > 0, current, -1)
    incoming = graphs.in_transitions[index].astype(jnp.int32)
    width = max(incoming.shape[-1], current.shape[-1])
    incoming = jnp.pad(incoming, ((0, 0), (0, width - incoming.shape[-1])), constant_values=-1)
    and_row = jnp.pad(current, (0, width - current.shape[-1]), constant_values=-1)
    incoming = incoming.at[0].set(and_row)
    succ = graphs.successor[index].astype(jnp.int32)
    succ_rows = jnp.full((succ.shape[-1], width), -1, jnp.int32).at[:, 0].set(succ)
    incoming = jnp.concatenate([incoming, succ_rows], axis=0)
    own = jnp.arange(incoming.shape[0])[:, None]
    neighbours = jnp.concatenate([own, incoming], axis=1)
    neighbour_mask = (neighbours >= 0) & node_mask[jnp.maximum(neighbours, 0)] & node_mask[own]
    return Graph(features * node_mask[:, None], node_mask, jnp.maximum(neighbours, 0),
                 neighbour_mask)


#: slot widths of the packed layout's first blocks: nodes with 0, 1, 2 in-neighbours besides
#: themselves (transition nodes and sinks have at most one); a last block holds the rest
BLOCK_WIDTHS = (0, 1, 2)


class NodeRows(NamedTuple):
    """The nodes of G graphs as the R rows of one array, in consecutive blocks of rows that share
    a slot width W_b (the padded layout is one block of all G * Nn rows).

    Attributes:
        features: float32[R, F] node features (zero on padding rows).
        row_mask: bool[R] live nodes.
        slots: int32[R_b, W_b] per block: the rows of each row's in-neighbours other than itself.
        slot_mask: bool[R_b, W_b] per block.
        roots: int32[G] the row of each graph's AND node.
    """

    features: jax.Array
    row_mask: jax.Array
    slots: tuple[jax.Array, ...]
    slot_mask: tuple[jax.Array, ...]
    roots: jax.Array


def padded_rows(graph: Graph) -> NodeRows:
    """G padded graphs (`Graph` with one batch axis) as G * Nn rows in one block of width D - 1."""
    num_graphs, num_nodes, width = graph.neighbours.shape
    offset = (jnp.arange(num_graphs) * num_nodes)[:, None, None]
    slots = (graph.neighbours[..., 1:] + offset).reshape(num_graphs * num_nodes, width - 1)
    mask = graph.neighbour_mask[..., 1:].reshape(num_graphs * num_nodes, width - 1)
    return NodeRows(graph.features.reshape(num_graphs * num_nodes, -1),
                    graph.node_mask.reshape(-1), (slots,), (mask,),
                    jnp.arange(num_graphs) * num_nodes)


def block_widths(num_slots: int) -> tuple[int, ...]:
    """Slot widths of the packed blocks for graphs of `num_slots` slots (self included)."""
    return tuple(min(w, num_slots - 1) for w in BLOCK_WIDTHS) + (num_slots - 1,)


def block_sizes(packing: Sequence[float], num_graphs: int, num_nodes: int, num_slots: int
                ) -> tuple[int, ...] | None:
    """Rows of each packed block for G = `num_graphs` graphs, given the rows per graph that each
    block is allowed (`packing`, one per `block_widths` entry); the last block gets one padded
    graph more. None where packing would not take fewer rows than the padded layout."""
    widths = block_widths(num_slots)
    if len(packing) != len(widths):
        raise ValueError(f"packing needs {len(widths)} allowances (blocks of widths {widths}), "
                         f"got {len(packing)}")
    sizes = [int(np.ceil(num_graphs * a)) for a in packing]
    sizes[-1] += num_nodes
    return None if sum(sizes) >= num_graphs * num_nodes else tuple(sizes)


def node_blocks(graph: Graph) -> jax.Array:
    """int32[..., Nn]: each live node's packed block (the first of `block_widths` that holds its
    in-neighbours other than itself); -1 for masked nodes."""
    widths = block_widths(graph.neighbours.shape[-1])
    degree = jnp.sum(graph.neighbour_mask[..., 1:], axis=-1)
    block = jnp.sum(degree[..., None] > jnp.asarray(widths[:-1]), axis=-1)
    return jnp.where(graph.node_mask, block, -1)


def pack_rows(graph: Graph, sizes: Sequence[int]) -> tuple[NodeRows, jax.Array]:
    """The live nodes of G graphs packed into blocks of `sizes` rows and `block_widths` slots,
    and whether they fit (bool[]).

    A node goes to the block of the fewest slots that hold its in-neighbours; a block that is
    full passes the rest of its nodes on to the next (wider) blocks. Within a node, the live
    slots come first (attention ignores slot order)."""
    num_graphs, num_nodes, num_slots = graph.neighbours.shape
    widths = block_widths(num_slots)
    total, flat = sum(sizes), num_graphs * num_nodes
    other = graph.neighbour_mask[..., 1:].reshape(flat, num_slots - 1)
    block = node_blocks(graph).reshape(flat)
    row = jnp.full(flat, total, jnp.int32)
    end, start = jnp.zeros((), jnp.int32), 0
    for b, size in enumerate(sizes):
        member = block == b
        first = jnp.maximum(start, end)
        row = jnp.where(member, first + jnp.cumsum(member) - 1, row)
        end, start = first + jnp.sum(member), start + size
    owner = jnp.full(total, -1, jnp.int32).at[row].set(jnp.arange(flat, dtype=jnp.int32),
                                                       mode="drop")
    row_mask = owner >= 0
    owner = jnp.maximum(owner, 0)
    features = graph.features.reshape(flat, -1)[owner] * row_mask[:, None]
    mask = other[owner] & row_mask[:, None]
    order = jnp.argsort(~mask, axis=-1, stable=True)
    mask = jnp.take_along_axis(mask, order, axis=-1)
    nodes = jnp.take_along_axis(graph.neighbours.reshape(flat, num_slots)[owner, 1:], order, -1)
    rows = row[(owner // num_nodes * num_nodes)[:, None] + nodes]
    rows = jnp.where(mask, rows, jnp.arange(total)[:, None])
    slots, slot_mask, start = [], [], 0
    for width, size in zip(widths, sizes):
        slots.append(rows[start:start + size, :width])
        slot_mask.append(mask[start:start + size, :width])
        start += size
    roots = row[jnp.arange(num_graphs) * num_nodes]
    return NodeRows(features, row_mask, tuple(slots), tuple(slot_mask), roots), end <= total


def packing_allowance(graphs: GraphBank, bank: DFABank, slack: float = 1.25,
                      spare: float = 0.5) -> tuple[float, ...]:
    """Rows per graph for each packed block: `slack` times the mean count of the block's nodes
    over the bank's graphs at their start states (the largest graph of each conjunction: an
    advanced graph only loses nodes, and a node keeps its in-neighbours), and `spare` rows more
    for the last block (it takes what overflows the others)."""
    index = jnp.arange(bank.size)
    q = jnp.zeros((bank.size, bank.max_conjuncts), jnp.int32)
    g = jax.jit(jax.vmap(graph_of, in_axes=(None, None, 0, 0)))(graphs, bank, index, q)
    blocks = np.asarray(jax.jit(node_blocks)(g))
    widths = block_widths(g.neighbours.shape[-1])
    means = [float((blocks == b).sum()) / bank.size for b in range(len(widths))]
    allowance = [slack * m for m in means]
    allowance[-1] += spare
    return tuple(allowance)


class DenseWeights(nn.Module):
    """A dense layer's parameters under `nn.Dense`'s names (`kernel` [in, out], `bias`),
    returned for the encoder's functions."""

    features_in: int
    features_out: int

    @nn.compact
    def __call__(self) -> tuple[jax.Array, jax.Array]:
        kernel = self.param("kernel", unit_columns, (self.features_in, self.features_out))
        return kernel, self.param("bias", nn.initializers.zeros_init(), (self.features_out,))


class GATv2Weights(nn.Module):
    """The shared GATv2 layer's parameters: `kernel` [2 F, 2 H F] mapping `[h, h0]` to the
    sender (first H F columns) and receiver projections, `bias`, `attention` [H, F]."""

    features: int = 64
    heads: int = 4

    @nn.compact
    def __call__(self) -> tuple[jax.Array, jax.Array, jax.Array]:
        width = self.heads * self.features
        kernel = self.param("kernel", unit_columns, (2 * self.features, 2 * width))
        bias = self.param("bias", nn.initializers.zeros_init(), (2 * width,))
        attn = self.param("attention", nn.initializers.xavier_normal(), (self.heads, self.features))
        return kernel, bias, attn


def _attend(message: jax.Array, valid: jax.Array, dst: jax.Array, attn: jax.Array
            ) -> jax.Array:
    """GATv2 aggregation for B receivers `dst` float32[B, H, F] over the messages of their
    slots `message` float32[B, 1 + W, H, F] (slot 0: their own; `valid` bool[B, 1 + W]).
    Returns float32[B, H, F]."""
    valid = valid[..., None]
    score = jnp.sum(nn.leaky_relu(message + dst[:, None], 0.2) * attn, axis=-1)  # [B, 1+W, H]
    score = jnp.where(valid, score, -jnp.inf)
    top = jax.lax.stop_gradient(jnp.max(score, axis=1, keepdims=True))
    weight = jnp.where(valid, jnp.exp(score - jnp.where(jnp.isfinite(top), top, 0.0)), 0.0)
    weight = weight / jnp.maximum(jnp.sum(weight, axis=1, keepdims=True), 1e-9)
    return jnp.sum(weight[..., None] * message, axis=1)


def encode_rows(embed: tuple[jax.Array, jax.Array], gat: tuple[jax.Array, jax.Array, jax.Array],
                num_layers: int, rows: NodeRows) -> jax.Array:
    """The AND nodes' hidden states float32[G, F] after `num_layers` rounds of the shared GATv2
    layer (4 heads on `[h, h0]`, tanh per head, heads summed) over `rows`."""
    kernel, bias, attn = gat
    heads, features = attn.shape
    width = heads * features
    # per block (split, whose transpose is a concatenation): rows, and the slots in one gather
    sizes = tuple(int(slots.shape[0]) for slots in rows.slots)
    gathered = tuple(int(slots.size) for slots in rows.slots)
    slots = jnp.concatenate([x.reshape(-1) for x in rows.slots])
    valid = [jnp.concatenate([own[:, None], mask], axis=1) for own, mask
             in zip(jax.lax.split(rows.row_mask, sizes), rows.slot_mask)]
    h0 = rows.features @ embed[0] + embed[1]
    # h0's half of [h, h0] @ kernel, the same every round
    static_src = h0 @ kernel[features:, :width] + bias[:width]
    static_dst = h0 @ kernel[features:, width:] + bias[width:]

    def layer(h, _):
        src = (h @ kernel[:features, :width] + static_src).reshape(-1, heads, features)
        dst = (h @ kernel[:features, width:] + static_dst).reshape(-1, heads, features)
        others = jax.lax.split(src[slots], gathered)
        parts = []
        for own, other, d, v in zip(jax.lax.split(src, sizes), others, jax.lax.split(dst, sizes),
                                    valid):
            message = jnp.concatenate([own[:, None], other.reshape(own.shape[0], -1, heads,
                                                                   features)], axis=1)
            parts.append(_attend(message, v, d, attn))
        return jnp.sum(jnp.tanh(jnp.concatenate(parts)), axis=1) * rows.row_mask[:, None], None

    h, _ = jax.lax.scan(layer, h0, length=num_layers)  # one shared layer, num_layers rounds
    return h[rows.roots]


#: graphs per step of a packed batch's padded fallback (`RADEncoder`)
PADDED_CHUNK = 256


class RADEncoder(nn.Module):
    """GATv2 over a cDFA `Graph` (leading batch axes allowed) -> float32[..., out].

    `packing` (rows per graph of each block, `packing_allowance`): a batch whose live nodes fit
    is encoded packed; one that does not, padded (the same numbers either way)."""

    hidden: int = 64
    heads: int = 4
    num_layers: int = 8
    out: int = 32
    packing: tuple[float, ...] | None = None

    @nn.compact
    def __call__(self, graph: Graph) -> jax.Array:
        batch = graph.node_mask.shape[:-1]
        graph = jax.tree.map(lambda x: x.reshape(-1, *x.shape[len(batch):]), graph)
        weights = (DenseWeights(graph.features.shape[-1], self.hidden, name="embed")(),
                   GATv2Weights(self.hidden, self.heads, name="gat")())
        encode = functools.partial(encode_rows, num_layers=self.num_layers)
        sizes = (None if self.packing is None
                 else block_sizes(self.packing, *graph.neighbours.shape))
        if sizes is None:
            h = encode(*weights, rows=padded_rows(graph))
        else:
            rows, fits = pack_rows(graph, sizes)

            def packed(weights, rows, graph):
                return encode(*weights, rows=rows)

            # rematerialised, or the packed branch would write (zero) residuals of the padded
            # one's size for the backward pass, costing more than packing saves; in chunks of
            # graphs, each rematerialised, so the rare padded batch takes little memory
            @jax.checkpoint
            def padded(weights, rows, graph):
                @jax.checkpoint
                def one(graph):
                    return encode(*weights, rows=padded_rows(jax.tree.map(lambda x: x[None],
                                                                          graph)))[0]

                return jax.lax.map(one, graph, batch_size=PADDED_CHUNK)

            h = jax.lax.cond(fits, packed, padded, weights, rows, graph)
        emb = nn.Dense(self.out, kernel_init=unit_columns, name="readout")(h)
        return emb.reshape(*batch, self.out)
