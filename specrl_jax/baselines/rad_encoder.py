"""RAD-Embeddings' encoder: the graph of a conjunction of DFAs as padded arrays, and the GATv2
network that embeds it (32-d).

Graph (the original's `DFABuilder`, one layer per DFA): one node per DFA state; for each state s
and each distinct successor e != s one *transition* node whose features are the multi-hot set of
symbols leading from s to e, with edges e -> transition -> s (messages flow from successors to
predecessors; self-loops of the DFA are not drawn); one AND node with an edge from each DFA's
current state; every node attends to itself. Node features: the A symbols, then the flags AND,
init (current state), normal (state node), temp (transition node), accepting, rejecting (a
non-accepting state whose every transition is a self-loop), at indices -6 .. -1 as the original.

The host builds, per conjunction of a bank, the graph of its full minimal DFAs once
(`build_graphs`); inside `jit`, `graph_of` masks the nodes that the current states can no longer
reach, flags the current states and draws the AND edges, so the graph is that of the advanced,
minimised conjunction (see `automata.rad_sampler`).

Encoder (the original's `GATv2Conv` entry): `h0 = W x`; 8 times one shared GATv2 layer of 4
heads on `[h, h0]` (128 -> 64 per head), tanh per head, heads summed; the AND node's hidden,
through a Dense layer to 32. GATv2: `e_ij = a . LeakyReLU_0.2(W_s x_j + W_d x_i)`, softmax over
the in-edges of i, `h_i = sum_j alpha_ij W_s x_j` (segment ops over a flattened batch).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.automata.rad_sampler import DFABank

NUM_FLAGS = 6
AND, INIT, NORMAL, TEMP, ACCEPTING, REJECTING = range(-6, 0)
KIND_PAD, KIND_AND, KIND_STATE, KIND_TRANSITION = 0, 1, 2, 3


def num_features(num_symbols: int) -> int:
    """Node feature width for an alphabet of `num_symbols` symbols."""
    return num_symbols + NUM_FLAGS


@struct.dataclass
class GraphBank:
    """The graphs of a `DFABank`'s conjunctions (K of them, Nn nodes, E edges each).

    Attributes:
        features: bool[K, Nn, F] node features without the init flag (F = A + 6).
        kind: int8[K, Nn] pad / AND / state / transition node.
        conjunct: int8[K, Nn] the node's DFA (-1: AND or padding).
        state: int8[K, Nn] a state node's state, a transition node's source state.
        state_node: int16[K, N, S] node of each DFA state (-1 none).
        senders, receivers: int16[K, E] the transition edges (-1 padding).
    """

    features: jax.Array
    kind: jax.Array
    conjunct: jax.Array
    state: jax.Array
    state_node: jax.Array
    senders: jax.Array
    receivers: jax.Array

    @property
    def num_nodes(self) -> int:
        return int(self.kind.shape[-1])


class Graph(NamedTuple):
    """One graph (leading batch axes allowed): `features` float32[Nn, F], `node_mask` bool[Nn],
    `senders`/`receivers` int32[E] with `edge_mask` bool[E]; node 0 is the AND node (readout).
    Self edges are implicit: every live node attends to itself."""

    features: jax.Array
    node_mask: jax.Array
    senders: jax.Array
    receivers: jax.Array
    edge_mask: jax.Array


def _cdfa_graph(delta: np.ndarray, accepting: np.ndarray, num_states: np.ndarray):
    """Nodes and edges of one conjunction's full DFAs (lists)."""
    num_symbols = delta.shape[-1]
    width = num_features(num_symbols)
    feats, kind, conj, state, senders, receivers = [], [], [], [], [], []
    and_row = np.zeros(width, bool)
    and_row[AND] = True
    feats.append(and_row), kind.append(KIND_AND), conj.append(-1), state.append(0)
    state_node = -np.ones(delta.shape[:2], np.int64)
    for n in range(delta.shape[0]):
        for s in range(num_states[n]):
            row = np.zeros(width, bool)
            row[NORMAL] = True
            row[ACCEPTING] = accepting[n, s]
            row[REJECTING] = (not accepting[n, s]) and bool(np.all(delta[n, s] == s))
            state_node[n, s] = len(kind)
            feats.append(row), kind.append(KIND_STATE), conj.append(n), state.append(s)
    for n in range(delta.shape[0]):
        for s in range(num_states[n]):
            for e in np.unique(delta[n, s]):
                if e == s:
                    continue
                row = np.zeros(width, bool)
                row[:num_symbols] = delta[n, s] == e
                row[TEMP] = True
                t = len(kind)
                feats.append(row), kind.append(KIND_TRANSITION), conj.append(n), state.append(s)
                senders += [state_node[n, e], t]
                receivers += [t, state_node[n, s]]
    return feats, kind, conj, state, state_node, senders, receivers


def build_graphs(bank: DFABank, max_nodes: int | None = None, max_edges: int | None = None
                 ) -> GraphBank:
    """The graphs of every conjunction of `bank`, padded to the bank's largest (or the caps)."""
    delta, accepting = np.asarray(bank.delta), np.asarray(bank.accepting)
    num_states = np.asarray(bank.num_states)
    graphs = [_cdfa_graph(delta[k], accepting[k], num_states[k]) for k in range(bank.size)]
    nodes = max(len(g[1]) for g in graphs) if max_nodes is None else max_nodes
    edges = max(max(len(g[5]) for g in graphs), 1) if max_edges is None else max_edges
    if any(len(g[1]) > nodes or len(g[5]) > edges for g in graphs):
        raise ValueError(f"a conjunction's graph exceeds max_nodes={nodes} or max_edges={edges}")
    k, width = bank.size, num_features(delta.shape[-1])
    out = {
        "features": np.zeros((k, nodes, width), bool),
        "kind": np.zeros((k, nodes), np.int8),
        "conjunct": -np.ones((k, nodes), np.int8),
        "state": np.zeros((k, nodes), np.int8),
        "state_node": np.stack([g[4] for g in graphs]).astype(np.int16),
        "senders": -np.ones((k, edges), np.int16),
        "receivers": -np.ones((k, edges), np.int16),
    }
    for i, (feats, kind, conj, state, _, senders, receivers) in enumerate(graphs):
        m, e = len(kind), len(senders)
        out["features"][i, :m] = np.stack(feats)
        out["kind"][i, :m], out["conjunct"][i, :m], out["state"][i, :m] = kind, conj, state
        out["senders"][i, :e], out["receivers"][i, :e] = senders, receivers
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
    senders = graphs.senders[index].astype(jnp.int32)
    receivers = graphs.receivers[index].astype(jnp.int32)
    edge_mask = ((senders >= 0) & node_mask[jnp.maximum(senders, 0)]
                 & node_mask[jnp.maximum(receivers, 0)])
    # one AND edge per used conjunct, from its current state
    current = graphs.state_node[index, jnp.arange(q.shape[-1]), q].astype(jnp.int32)
    and_mask = bank.num_states[index] > 0
    return Graph(
        features * node_mask[:, None],
        node_mask,
        jnp.concatenate([jnp.maximum(senders, 0), jnp.maximum(current, 0)]),
        jnp.concatenate([jnp.maximum(receivers, 0), jnp.zeros_like(current)]),
        jnp.concatenate([edge_mask, and_mask]),
    )


def unit_columns(key: jax.Array, shape: Sequence[int], dtype: Any = jnp.float32) -> jax.Array:
    """The original's `init_params` for linear layers: N(0, 1) weights with each output unit's
    weight vector scaled to unit L2 norm."""
    w = jax.random.normal(key, shape, dtype)
    return w / jnp.linalg.norm(w, axis=0, keepdims=True)


class GATv2Layer(nn.Module):
    """One GATv2 convolution of `heads` heads, `features` each, tanh per head, heads summed.

    Args (call): x float32[M, D] node inputs of a flattened batch, senders/receivers int32[Ed]
    (self edges included), edge_mask bool[Ed]. Returns float32[M, features].
    """

    features: int = 64
    heads: int = 4

    @nn.compact
    def __call__(self, x: jax.Array, senders: jax.Array, receivers: jax.Array,
                 edge_mask: jax.Array) -> jax.Array:
        num_nodes = x.shape[0]
        width = self.heads * self.features
        src = nn.Dense(width, kernel_init=unit_columns, name="src")(x)
        dst = nn.Dense(width, kernel_init=unit_columns, name="dst")(x)
        attn = self.param("attention", nn.initializers.xavier_normal(), (self.heads, self.features))
        src = src.reshape(num_nodes, self.heads, self.features)
        dst = dst.reshape(num_nodes, self.heads, self.features)
        message = src[senders]  # [Ed, H, F]
        score = jnp.sum(nn.leaky_relu(message + dst[receivers], 0.2) * attn, axis=-1)  # [Ed, H]
        segment = jnp.where(edge_mask, receivers, num_nodes)  # masked edges: a dropped segment
        top = jax.ops.segment_max(score, segment, num_segments=num_nodes + 1)
        weight = jnp.exp(score - jax.lax.stop_gradient(top[segment]))
        weight = jnp.where(edge_mask[:, None], weight, 0.0)
        norm = jax.ops.segment_sum(weight, segment, num_segments=num_nodes + 1)
        total = jax.ops.segment_sum(weight[..., None] * message, segment,
                                    num_segments=num_nodes + 1)[:num_nodes]
        out = total / jnp.maximum(norm[:num_nodes], 1e-9)[..., None]
        return jnp.sum(jnp.tanh(out), axis=1)


class RADEncoder(nn.Module):
    """GATv2 over a cDFA `Graph` (leading batch axes allowed) -> float32[..., out]."""

    hidden: int = 64
    heads: int = 4
    num_layers: int = 8
    out: int = 32

    @nn.compact
    def __call__(self, graph: Graph) -> jax.Array:
        batch, num_nodes = graph.node_mask.shape[:-1], graph.node_mask.shape[-1]
        features = graph.features.reshape(-1, num_nodes, graph.features.shape[-1])
        node_mask = graph.node_mask.reshape(-1, num_nodes)
        num_graphs = features.shape[0]
        offsets = (jnp.arange(num_graphs) * num_nodes)[:, None]
        senders = graph.senders.reshape(num_graphs, -1) + offsets
        receivers = graph.receivers.reshape(num_graphs, -1) + offsets
        total = num_graphs * num_nodes
        own = jnp.arange(total)
        senders = jnp.concatenate([senders.reshape(-1), own])
        receivers = jnp.concatenate([receivers.reshape(-1), own])
        edge_mask = jnp.concatenate([graph.edge_mask.reshape(-1), node_mask.reshape(-1)])
        h0 = nn.Dense(self.hidden, kernel_init=unit_columns, name="embed")(
            features.reshape(total, -1))
        layer = GATv2Layer(self.hidden, self.heads, name="gat")
        h = h0
        for _ in range(self.num_layers):  # one shared layer, applied num_layers times
            h = layer(jnp.concatenate([h, h0], axis=-1), senders, receivers, edge_mask)
        root = h.reshape(num_graphs, num_nodes, self.hidden)[:, 0]
        emb = nn.Dense(self.out, kernel_init=unit_columns, name="readout")(root)
        return emb.reshape(*batch, self.out)
