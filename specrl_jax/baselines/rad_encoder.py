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
attention softmax over them: the sums of segment ops over an edge list, without a scatter
(XLA's scatter made the encoder 10x slower on a CPU). All nodes go through one gather and one
softmax (separate ones for the two node blocks crashed XLA:CPU under nested vmaps).

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

from collections.abc import Sequence
from typing import Any, NamedTuple

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


def _gather_nodes(src: jax.Array, ids: jax.Array) -> jax.Array:
    """`src[g, ids[g, ...]]` for float32[G, Nn, H, F] and int32[G, ...] (one flat gather)."""
    num_graphs, num_nodes = src.shape[:2]
    offsets = (jnp.arange(num_graphs) * num_nodes).reshape(-1, *([1] * (ids.ndim - 1)))
    return src.reshape(num_graphs * num_nodes, *src.shape[2:])[ids + offsets]


def _attend(src: jax.Array, dst: jax.Array, slots: jax.Array, mask: jax.Array,
            attn: jax.Array) -> jax.Array:
    """GATv2 aggregation for receivers `dst` float32[G, R, H, F] over their in-neighbour slots
    `slots` int32[G, R, D] (node ids within the graph; `mask` bool[G, R, D]) of the senders'
    `src` float32[G, Nn, H, F]. Returns float32[G, R, H, F]."""
    message = _gather_nodes(src, slots)
    score = jnp.sum(nn.leaky_relu(message + dst[:, :, None], 0.2) * attn, axis=-1)  # [G, R, D, H]
    score = jnp.where(mask[..., None], score, -jnp.inf)
    top = jax.lax.stop_gradient(jnp.max(score, axis=2, keepdims=True))
    weight = jnp.where(mask[..., None], jnp.exp(score - jnp.where(jnp.isfinite(top), top, 0.0)),
                       0.0)
    weight = weight / jnp.maximum(jnp.sum(weight, axis=2, keepdims=True), 1e-9)
    return jnp.sum(weight[..., None] * message, axis=2)


class GATv2Layer(nn.Module):
    """One GATv2 convolution on `[h, h0]` of `heads` heads, `features` each, tanh per head,
    heads summed.

    Args (call): h, h0 float32[G, Nn, features] node states of G graphs, and the graphs
    (`neighbours`, `neighbour_mask` [G, Nn, D]).
    Returns float32[G, Nn, features].
    """

    features: int = 64
    heads: int = 4

    @nn.compact
    def __call__(self, h: jax.Array, h0: jax.Array, graph: Graph) -> jax.Array:
        width = self.heads * self.features
        kernel = self.param("kernel", unit_columns, (2 * self.features, 2 * width))
        bias = self.param("bias", nn.initializers.zeros_init(), (2 * width,))
        attn = self.param("attention", nn.initializers.xavier_normal(), (self.heads, self.features))
        # [h, h0] @ kernel, with h0's half the same in every round (XLA computes it once)
        both = h @ kernel[:self.features] + (h0 @ kernel[self.features:] + bias)
        shape = (*h.shape[:2], self.heads, self.features)
        src, dst = both[..., :width].reshape(shape), both[..., width:].reshape(shape)
        out = _attend(src, dst, graph.neighbours, graph.neighbour_mask, attn)
        return jnp.sum(jnp.tanh(out), axis=2)


class RADEncoder(nn.Module):
    """GATv2 over a cDFA `Graph` (leading batch axes allowed) -> float32[..., out]."""

    hidden: int = 64
    heads: int = 4
    num_layers: int = 8
    out: int = 32

    @nn.compact
    def __call__(self, graph: Graph) -> jax.Array:
        batch = graph.node_mask.shape[:-1]
        graph = jax.tree.map(lambda x: x.reshape(-1, *x.shape[len(batch):]), graph)
        h0 = nn.Dense(self.hidden, kernel_init=unit_columns, name="embed")(graph.features)
        layer = GATv2Layer(self.hidden, self.heads, name="gat")
        h = h0
        for _ in range(self.num_layers):  # one shared layer, applied num_layers times
            h = layer(h, h0, graph) * graph.node_mask[..., None]
        emb = nn.Dense(self.out, kernel_init=unit_columns, name="readout")(h[:, 0])
        return emb.reshape(*batch, self.out)
