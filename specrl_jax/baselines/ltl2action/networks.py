"""LTL2Action's networks: the relational GCN over the progressed formula's syntax tree and the
actor-critic that reads its embedding beside the observation.

The network reads each sample's formula state, an index into its progression bank's graphs
(`FormulaObs`). A node's hidden state depends only on the parameters and the subtree below it
(messages run child -> parent), so equal subtrees have equal states wherever they occur: the
R-GCN can run once over the bank's distinct subtrees (`FormulaDag`, 2,929 nodes for the 2,171
Zone curriculum states, whose trees hold 41,959) and each sample gather its state's root
(`embed_formulas`, where that is less work than the samples' own padded trees); the outputs and
gradients are the same up to float reassociation.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.baselines.encoders import check_image_dtype, check_kinds
from specrl_jax.baselines.heads import dense as _dense
from specrl_jax.baselines.heads import embedding_actor_critic
from specrl_jax.baselines.ppo.networks import PolicyOutput
from specrl_jax.tasks.progression import NUM_EDGE_TYPES, ProgressionBank, num_features
from specrl_jax.tasks.sources import ByContent

#: the R-GCN's submodule name in the LTL2Action and pretraining networks (what transfers)
ENCODER = "RGCNEncoder_0"  # flax's automatic name, kept so that saved parameters load


def relation_kernel_init(key: jax.Array, shape: Sequence[int],
                         dtype: jnp.dtype = jnp.float32) -> jax.Array:
    """DGL 0.4.3 `RelGraphConv`'s basis weights `[R, in, out]`: `xavier_uniform_` with ReLU gain
    under PyTorch's fans for a 3-D tensor (fan_in = in * out, fan_out = R * out), i.e.
    U(-b, b) with b = sqrt(2) sqrt(6 / (in * out + R * out)); 0.0743 for [4, 64, 32]."""
    num_rels, num_in, out = shape
    bound = np.sqrt(2.0) * np.sqrt(6.0 / (num_in * out + num_rels * out))
    return jax.random.uniform(key, shape, dtype, -bound, bound)


class FormulaGraphs(ByContent):
    """A progression bank's syntax trees (see `tasks.progression.ProgressionBank`) as static
    metadata of `FormulaObs`, compared by content: `tokens` int16[S, N] (-1 padding), `parent`
    int16[S, N] (-1: root or padding), `edge` int8[S, N]."""

    def __init__(self, bank: ProgressionBank):
        super().__init__(tuple(np.asarray(x) for x in (bank.tokens, bank.parent, bank.edge)))

    @property
    def num_states(self) -> int:
        return int(self.tree[0].shape[0])

    @property
    def num_nodes(self) -> int:
        """N: node slots of each padded tree."""
        return int(self.tree[0].shape[1])

    def graph(self, state: jax.Array | None = None) -> tuple[jax.Array, jax.Array, jax.Array]:
        """`(tokens, parent, edge)` of formula state `state` (int[...]), each [..., N]; all S
        states' ([S, N]) where `state` is None."""
        if state is None:
            return tuple(jnp.asarray(x) for x in self.tree)
        return tuple(jnp.asarray(x)[state] for x in self.tree)

    @functools.cached_property
    def dag(self) -> FormulaDag:
        """The bank's trees with equal subtrees merged (`formula_dag`), as numpy arrays."""
        return formula_dag(*self.tree)


class FormulaDag(NamedTuple):
    """A bank's syntax trees with equal subtrees merged into one node: D distinct subtrees and
    the E child -> parent edges between them (a child used twice by a parent, twice). The
    R-GCN reads padded trees in this form too (`padded_forest`)."""

    tokens: np.ndarray  # int32[D], each subtree's root token
    child: np.ndarray  # int32[E]
    parent: np.ndarray  # int32[E]
    edge: np.ndarray  # int32[E], the edge's type
    roots: np.ndarray  # int32[S], each state's whole tree (-1: an empty tree)


def formula_dag(tokens: np.ndarray, parent: np.ndarray, edge: np.ndarray) -> FormulaDag:
    """Merge equal subtrees of padded trees (`tokens`, `parent`, `edge` [S, N], nodes in
    preorder, so each child after its parent): a subtree is its root token and the multiset of
    its (child subtree, edge type) pairs."""
    ids: dict[tuple, int] = {}
    dag_tokens, child_ids, parent_ids, edge_types = [], [], [], []
    roots = np.full(tokens.shape[0], -1, np.int32)
    for s in range(tokens.shape[0]):
        live = int(np.sum(tokens[s] >= 0))
        if not ((tokens[s, :live] >= 0).all() and (parent[s, 1:live] < np.arange(1, live)).all()):
            raise ValueError(f"tree {s}: nodes must come first, each after its parent (preorder)")
        below: list[list[tuple[int, int]]] = [[] for _ in range(live)]
        for k in range(live - 1, -1, -1):  # children first
            key = (int(tokens[s, k]), tuple(sorted(below[k])))
            if key not in ids:
                ids[key] = len(dag_tokens)
                dag_tokens.append(key[0])
                for sub, kind in key[1]:
                    child_ids.append(sub)
                    parent_ids.append(ids[key])
                    edge_types.append(kind)
            if parent[s, k] >= 0:
                below[int(parent[s, k])].append((ids[key], int(edge[s, k])))
            else:
                roots[s] = ids[key]
    lists = (np.asarray(x, np.int32).reshape(-1)
             for x in (dag_tokens, child_ids, parent_ids, edge_types))
    return FormulaDag(*lists, roots)


@struct.dataclass
class FormulaObs:
    """What the LTL2Action network reads (one env; leading batch axes allowed): the world
    observation as encoder parts and the progressed formula as `state` int32[] (a row of
    `graphs`, the bank's syntax trees)."""

    parts: dict
    state: jax.Array
    graphs: FormulaGraphs = struct.field(pytree_node=False)


class RGCNEncoder(nn.Module):
    """LTL2Action's `RGCN_8x32_ROOT_SHARED` with segment sums.

    `h0 = W_in x` (x one-hot node tokens); `num_layers` times the one shared relational
    convolution `h_i <- tanh(sum_r sum_{j in N_r(i)} W_r [h_j, h0_j] + b)` over the self edge
    (type 0) and the child -> parent edges (types 1-3); the root's hidden, through a Dense layer.
    Node order does not matter: only the parent links and edge types do. The relation weights
    start as DGL 0.4.3's (`relation_kernel_init`), the Dense layers as the original's.
    """

    features: int
    hidden: int = 32
    num_layers: int = 8
    out: int = 32

    @nn.compact
    def __call__(self, tokens: jax.Array | FormulaDag, parent: jax.Array | None = None,
                 edge: jax.Array | None = None) -> jax.Array:
        """Padded trees `(tokens, parent, edge)`, each [..., N] -> [..., out]; or a
        `FormulaDag` -> its S states' embeddings [S, out]."""
        dag = tokens if isinstance(tokens, FormulaDag) else padded_forest(tokens, parent, edge)
        nodes, child, receiver, kind, roots = (jnp.asarray(x, jnp.int32) for x in dag)
        total = nodes.size
        h0 = _dense(self.hidden)(jax.nn.one_hot(nodes, self.features))  # [M, H]
        weight = self.param("relation_kernel", relation_kernel_init,
                            (NUM_EDGE_TYPES, 2 * self.hidden, self.hidden))
        bias = self.param("relation_bias", nn.initializers.zeros_init(), (self.hidden,))

        def convolve(_, h):
            x = jnp.concatenate([h, h0], axis=-1)
            by_type = jnp.einsum("nd,rdo->nro", x, weight)  # [M, R, H]
            message = by_type[child, kind]  # one per child -> parent edge
            incoming = jax.ops.segment_sum(message, receiver, num_segments=total + 1)[:total]
            return jnp.tanh(by_type[:, 0] + incoming + bias)

        # one shared convolution: a loop keeps the compiled program one layer long
        h = jax.lax.fori_loop(0, self.num_layers, convolve, h0)
        h = jnp.concatenate([h, jnp.zeros((1, self.hidden), h.dtype)])  # root -1: an empty tree
        out = _dense(self.out)(h[roots])
        return out if dag is tokens else out.reshape(*tokens.shape[:-1], self.out)


def padded_forest(tokens: jax.Array, parent: jax.Array, edge: jax.Array) -> FormulaDag:
    """Padded trees (each [..., N]) as one graph of their node slots: an edge from every live
    non-root node to its parent, padding slots sending to a spare node (index M, dropped), and
    each tree's root (-1 for an empty tree)."""
    num_nodes = tokens.shape[-1]
    tokens, parent = (x.reshape(-1, num_nodes).astype(jnp.int32) for x in (tokens, parent))
    offsets = (jnp.arange(tokens.shape[0]) * num_nodes)[:, None]
    live = tokens >= 0
    receiver = jnp.where(live & (parent >= 0), parent + offsets, tokens.size)
    is_root = live & (parent < 0)
    roots = jnp.where(is_root.any(-1), jnp.argmax(is_root, -1) + offsets[:, 0], -1)
    return FormulaDag(tokens.reshape(-1), jnp.arange(tokens.size), receiver.reshape(-1),
                      edge.reshape(-1), roots)


def uses_dag(graphs: FormulaGraphs, num_samples: int) -> bool:
    """Whether `embed_formulas` runs the R-GCN once over the bank's distinct subtrees (fewer
    nodes than the `num_samples` padded trees of a forward pass hold) rather than over each
    sample's tree."""
    return graphs.dag.tokens.size < num_samples * graphs.num_nodes


def embed_formulas(encoder: RGCNEncoder, obs: FormulaObs) -> jax.Array:
    """float32[..., out]: the embedding of each sample's formula state (`obs.state` int[...]):
    rows of the bank's table (the R-GCN over its distinct subtrees, `FormulaDag`, [S, out])
    gathered by state where that is fewer nodes, else the R-GCN over each sample's tree. The
    choice is static: under `vmap` (seeds) the samples are one slice's."""
    if uses_dag(obs.graphs, obs.state.size):
        return encoder(obs.graphs.dag)[obs.state]
    return encoder(*obs.graphs.graph(obs.state))


class LTL2ActionNetwork(nn.Module):
    """Observation encoder (grid CNN, vector MLP [128, 64] ReLU, image CNN) and the R-GCN formula
    embedding (`embed_formulas`), concatenated; actor [64, 64, 64] ReLU then logits (or a
    Gaussian with Tanh mean and state-dependent std); critic [64, 64] Tanh. `freeze_encoder`: no
    gradient reaches the R-GCN (the original's `--freeze-ltl`)."""

    num_actions: int  # discrete actions, or the action dimension when `continuous`
    propositions: tuple[str, ...]
    continuous: bool = False
    freeze_encoder: bool = False
    image_dtype: str = "float32"

    @nn.compact
    def __call__(self, obs: FormulaObs) -> PolicyOutput:
        formula = embed_formulas(
            RGCNEncoder(num_features(len(self.propositions)), name=ENCODER), obs)
        if self.freeze_encoder:
            formula = jax.lax.stop_gradient(formula)
        return embedding_actor_critic(obs.parts, formula, self.num_actions, self.continuous,
                                      self.image_dtype)


def network_for(world: Any, freeze_encoder: bool = False,
                image_dtype: str = "float32") -> LTL2ActionNetwork:
    """The LTL2Action network for a world's action space and propositions."""
    check_kinds(world.obs_kinds)
    space, props = world.action_space, tuple(world.propositions)
    image_dtype = check_image_dtype(image_dtype)
    if hasattr(space, "n"):
        return LTL2ActionNetwork(int(space.n), props, freeze_encoder=freeze_encoder,
                                 image_dtype=image_dtype)
    return LTL2ActionNetwork(int(space.shape[0]), props, continuous=True,
                             freeze_encoder=freeze_encoder, image_dtype=image_dtype)


def with_encoder(params: Any, encoder: Any) -> Any:
    """`params` of a network with an `ENCODER` submodule, that submodule's parameters replaced
    by `encoder` (an R-GCN's `{"params": ...}`, e.g. `pretrain.encoder_params`).

    Raises:
        ValueError: `encoder` does not have the network's encoder's shapes.
    """
    own, given = params["params"][ENCODER], encoder["params"]
    shapes = jax.tree.map(np.shape, own), jax.tree.map(np.shape, given)
    if shapes[0] != shapes[1]:
        raise ValueError(f"the pretrained encoder's parameters {shapes[1]} do not match the "
                         f"network's R-GCN {shapes[0]} (another number of propositions?)")
    return {**params, "params": {**params["params"], ENCODER: jax.tree.map(jnp.asarray, given)}}
