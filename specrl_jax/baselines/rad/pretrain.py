"""Pretraining RAD-Embeddings' encoder on the symbol-only task, through the shared PPO.

The original (`Dummy-MDP-v0` / `Simple-LTL-Env-v0`): no observation; the action names the symbol
that occurs this step; the task is a RAD conjunction of DFAs, +1 and the end of the episode when
every DFA accepts, -1 and the end when one can no longer accept; horizon 75 (Letter) / 1000
(Zone). Here `SymbolWorld` is that world over any alphabet (its action is an alphabet row,
including the empty assignment, a no-op for RAD DFAs), run by the one task loop over a
`DFASource`. The network is the GATv2 encoder with linear actor and critic heads (`--dumb-ac`);
it encodes each batch of graphs packed to its live nodes (`rad_encoder.pack_rows`, rows sized by
the bank's `packing_allowance`), the same numbers as padded at a fraction of the cost.
PPO as the original: gamma 0.9, GAE lambda 0.5, lr 1e-3, clip 0.1, 2 epochs, entropy 0.01,
16 envs x 512 steps in minibatches of 1,024, 10M steps.

The encoder's parameters are saved as `specrl_jax/baselines/data/rad_encoder_<family>.msgpack`
(`save_encoder`, `load_encoder`) with a JSON beside it saying how they were made.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from specrl_jax import families
from specrl_jax.automata import rad_sampler
from specrl_jax.automata.rad_sampler import DFABank
from specrl_jax.baselines.params_io import DATA_DIR, load_encoder_file, save_params
from specrl_jax.baselines.ppo.networks import Categorical, PolicyOutput, unit_columns
from specrl_jax.baselines.ppo.train import Method
from specrl_jax.baselines.pretraining import SymbolWorld, pretrain_config, run_pretraining
from specrl_jax.baselines.rad.encoder import (
    NUM_FLAGS,
    GraphBank,
    RADEncoder,
    build_graphs,
    graph_of,
    num_features,
    packing_allowance,
)
from specrl_jax.baselines.train_env import TaskTrainEnv
from specrl_jax.tasks import TaskEnv
from specrl_jax.tasks.dfa_source import DFASource

#: graph nodes of a sampled conjunction at most (about the 97th percentile over 12 letters;
#: larger draws are redrawn, docs/fidelity.md): the encoder's cost grows with the padded size
MAX_GRAPH_NODES = 40


class DFAObs(NamedTuple):
    """A task as the pretraining network reads it: conjunction `index` int32[] of the bank and
    the state of each conjunct `q` int32[N] (leading batch axes allowed)."""

    index: jax.Array
    q: jax.Array


class Banks:
    """A DFA bank, its graphs and their packing allowance (`rad_encoder.packing_allowance`), held
    by a network as one static attribute (by identity)."""

    def __init__(self, bank: DFABank, graphs: GraphBank):
        self.bank, self.graphs = bank, graphs
        self.packing = packing_allowance(graphs, bank)

    def graph(self, obs: DFAObs):
        """The graphs of a batch of tasks (any leading axes)."""
        batch = obs.index.shape
        index, q = obs.index.reshape(-1), obs.q.reshape(-1, obs.q.shape[-1])
        g = jax.vmap(graph_of, in_axes=(None, None, 0, 0))(self.graphs, self.bank, index, q)
        return jax.tree.map(lambda x: x.reshape(*batch, *x.shape[1:]), g)


class PretrainNetwork(nn.Module):
    """The encoder (submodule `encoder`) with a linear actor over the A symbols and a linear
    critic, as the original's `--dumb-ac`."""

    banks: Banks
    num_actions: int
    hidden: int = 64  # the encoder's sizes (the original's by default)
    num_layers: int = 8

    @nn.compact
    def __call__(self, obs: DFAObs) -> PolicyOutput:
        encoder = RADEncoder(self.hidden, num_layers=self.num_layers,
                             packing=self.banks.packing, name="encoder")
        emb = encoder(self.banks.graph(obs))
        logits = nn.Dense(self.num_actions, kernel_init=unit_columns, name="actor")(emb)
        value = nn.Dense(1, kernel_init=unit_columns, name="critic")(emb)[..., 0]
        zeros = jnp.zeros_like(value)
        return PolicyOutput(Categorical(logits), value, zeros, zeros)


class RADPretrain(Method):
    """The symbol task as a method for the shared trainer."""

    def __init__(self, env: TaskTrainEnv, network: PretrainNetwork):
        self.env, self.network = env, network

    def init_task_params(self) -> None:
        return None

    def update_task_params(self, task_params: Any, stats: dict[str, jax.Array]) -> Any:
        return task_params


def signals(info: dict[str, Any]) -> tuple[jax.Array, jax.Array, jax.Array]:
    """RAD's reward: +1 on success, -1 on violation, else 0."""
    reward = info["success"].astype(jnp.float32) - info["violation"].astype(jnp.float32)
    return reward, jnp.zeros((), jnp.float32), jnp.zeros((), bool)


def make_pretrain(alphabet: np.ndarray, propositions: tuple[str, ...], family: str = "letter",
                  bank_size: int = 8192, seed: int = 0, bank: DFABank | None = None,
                  max_size: int | None = MAX_GRAPH_NODES, **encoder_sizes: int) -> RADPretrain:
    """The symbol task over `alphabet` on a bank of `bank_size` RAD conjunctions (or `bank`) of
    graphs of at most `max_size` nodes; `encoder_sizes` (hidden, num_layers) for small tests."""
    # the symbol task's horizon is the family's (the original's Simple-LTL envs: 75 / 1000)
    world = SymbolWorld(alphabet, propositions, families.get(family).horizon)
    if bank is None:
        bank = rad_sampler.sample_bank(bank_size, alphabet, seed, max_size)
    banks = Banks(bank, build_graphs(bank))

    def observe(obs, state):
        return DFAObs(state.task.index, state.task.q)

    task = TaskEnv(world, DFASource(bank, world.alphabet), observe)
    network = PretrainNetwork(banks, int(world.alphabet.shape[0]), **encoder_sizes)
    return RADPretrain(TaskTrainEnv(task, world.default_params, signals), network)


def encoder_params(params: Any) -> Any:
    """The encoder's part of a pretraining network's parameters."""
    return {"params": params["params"]["encoder"]}


def encoder_path(family: str) -> Path:
    return DATA_DIR / f"rad_encoder_{family}.msgpack"


def save_encoder(path: str | Path, params: Any, meta: dict[str, Any]) -> None:
    """Write encoder parameters and how they were made (`meta`)."""
    save_params(path, params, meta)


def pretrain_encoder(alphabet: np.ndarray, propositions: tuple[str, ...], family: str,
                     key: jax.Array, steps: int, bank_size: int = 8192, seed: int = 0,
                     log: Callable[[str], None] = print, chunk_updates: int = 50,
                     **ppo_overrides: Any) -> Any:
    """Pretrain the encoder on the symbol task over `alphabet` (a bank of `bank_size` RAD
    conjunctions) for about `steps` env steps of `pretrain_config(**ppo_overrides)`; returns
    `encoder_params` of the result."""
    method = make_pretrain(alphabet, propositions, family, bank_size, seed)
    config = pretrain_config(total_timesteps=max(int(steps), 1), **ppo_overrides)
    return encoder_params(run_pretraining(method, config, key, "RAD pretraining", log,
                                          chunk_updates))


def load_encoder(family_or_path: str | Path, num_symbols: int) -> Any:
    """Encoder parameters for an alphabet of `num_symbols` symbols, from the shipped file of a
    world family ("letter", "zone") or a path.

    Raises:
        ValueError: no such file, or the file is for another alphabet size.
    """
    path, stored, width = load_encoder_file(family_or_path, encoder_path, "rad", "RAD", "embed")
    if width != num_features(num_symbols):
        raise ValueError(f"the encoder at {path} reads {width - NUM_FLAGS} symbols; the "
                         f"alphabet has {num_symbols}; RAD needs an encoder pretrained on this "
                         "alphabet (`encoder=PATH`)")
    return jax.tree.map(jnp.asarray, stored)
