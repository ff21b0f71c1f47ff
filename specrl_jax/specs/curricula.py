"""Training curricula as data (DeepLTL, GenZ-LTL) and a jittable sampler / stage-advancer.

A curriculum is a tuple of stages; a stage is a mixture of sequence samplers with a success
threshold. `CurriculumSampler` turns one into pure functions over a `CurriculumState`:
`sample(key, state)` draws a training sequence for the current stage and `update(state, ...)`
advances the stage from the episodes that finished in a rollout (call it between PPO updates).

Stage advancement follows DeepLTL: per-task success = #success / #finished over the rollout's
finished episodes; the stage ends when the mean (or min) over tasks reaches its threshold.
Enumerated stages identify a task by its index; in sampled stages every episode counts as its
own task (see docs/fidelity.md).
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Sequence
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.specs import sequences as seqs
from specrl_jax.specs.formulas import sequence_to_formula


@dataclasses.dataclass(frozen=True)
class ReachAvoid:
    """Random reach-avoid sequences (`sequences.sample_reach_avoid`)."""

    depth: int
    num_reach: tuple[int, int]
    num_avoid: tuple[int, int]


@dataclasses.dataclass(frozen=True)
class ReachStay:
    """Reach-stay tasks (`sequences.sample_reach_stay`)."""

    num_stay: int
    num_avoid: tuple[int, int]


@dataclasses.dataclass(frozen=True)
class AllReach:
    """Every `depth`-step single-proposition reach chain (`sequences.all_reach_tasks`)."""

    depth: int


@dataclasses.dataclass(frozen=True)
class AllReachAvoid:
    """Every `depth`-step one-reach one-avoid chain (`sequences.all_reach_avoid_tasks`)."""

    depth: int


@dataclasses.dataclass(frozen=True)
class GenZSubgoals:
    """GenZ-LTL one-step subgoals (`sequences.genz_tasks`), drawn uniformly."""

    max_avoid: int = 3


Sampler = ReachAvoid | ReachStay | AllReach | AllReachAvoid | GenZSubgoals
_ENUMERATED = (AllReach, AllReachAvoid, GenZSubgoals)


@dataclasses.dataclass(frozen=True)
class Stage:
    """One curriculum stage.

    Attributes:
        samplers: the mixture components; an enumerated sampler must be alone in its stage.
        probs: mixture weights, one per sampler.
        threshold: success level that ends the stage; None = never ends.
        aggregate: "mean" or "min" over the tasks seen in a rollout.
        temperature: enumerated stages draw tasks with softmax(-success / temperature);
            None = uniform.
    """

    samplers: tuple[Sampler, ...]
    probs: tuple[float, ...] = (1.0,)
    threshold: float | None = None
    aggregate: Literal["mean", "min"] = "mean"
    temperature: float | None = None

    def __post_init__(self) -> None:
        if not self.samplers or len(self.probs) != len(self.samplers):
            raise ValueError(f"need one prob per sampler, got {self.samplers!r} / {self.probs!r}")
        if any(isinstance(s, _ENUMERATED) for s in self.samplers) and len(self.samplers) > 1:
            raise ValueError(f"an enumerated sampler must be alone in its stage: {self.samplers!r}")
        if self.aggregate not in ("mean", "min"):
            raise ValueError(f"aggregate must be 'mean' or 'min', got {self.aggregate!r}")

    @property
    def is_enumerated(self) -> bool:
        return isinstance(self.samplers[0], _ENUMERATED)


@dataclasses.dataclass(frozen=True)
class Curriculum:
    name: str
    stages: tuple[Stage, ...]

    @property
    def max_len(self) -> int:
        """The longest sequence any stage emits (pairs, before repeats)."""
        return max(_length(s) for stage in self.stages for s in stage.samplers)


def _length(sampler: Sampler) -> int:
    if isinstance(sampler, ReachStay):
        return 2
    if isinstance(sampler, GenZSubgoals):
        return 1
    return sampler.depth


DEEPLTL_LETTER = Curriculum(
    "deepltl/letter",
    (
        Stage((AllReachAvoid(1),), threshold=0.95, temperature=0.1),
        Stage((ReachAvoid(1, (1, 2), (0, 2)),), threshold=0.95),
        Stage((ReachAvoid(2, (1, 2), (1, 2)),), threshold=0.95),
        Stage((ReachAvoid(3, (1, 2), (0, 3)),)),
    ),
)

# The reference gives temperature 0.5 for stage 0 only; stages 1-3 reuse it.
DEEPLTL_ZONE = Curriculum(
    "deepltl/zone",
    (
        Stage((AllReach(1),), threshold=0.8, aggregate="min", temperature=0.5),
        Stage((AllReach(2),), threshold=0.95, temperature=0.5),
        Stage((AllReachAvoid(1),), threshold=0.95, temperature=0.5),
        Stage((AllReachAvoid(2),), threshold=0.9, temperature=0.5),
        Stage((ReachAvoid(1, (1, 2), (0, 2)), ReachStay(30, (0, 1))), (0.4, 0.6), 0.9),
        Stage((ReachAvoid(2, (1, 2), (1, 2)), ReachStay(60, (0, 1))), (0.8, 0.2), 0.9),
        Stage((ReachAvoid(3, (1, 2), (0, 3)), ReachStay(60, (0, 2))), (0.8, 0.2)),
    ),
)

GENZ_LETTER = Curriculum(
    "genz/letter", (Stage((GenZSubgoals(3),), threshold=0.99, aggregate="min"),)
)
GENZ_ZONE = Curriculum("genz/zone", (Stage((GenZSubgoals(3),), threshold=0.99, aggregate="min"),))

CURRICULA = {c.name: c for c in (DEEPLTL_LETTER, DEEPLTL_ZONE, GENZ_LETTER, GENZ_ZONE)}


def with_stay(base: Curriculum, steps: int) -> Curriculum:
    """`base` with its reach-stay tasks' stays scaled so that the longest is `steps` env steps
    (their ratios kept: DeepLTL's Zone 30 / 60 becomes steps / 2 / steps)."""
    if isinstance(steps, bool) or not isinstance(steps, int | np.integer) or steps < 1:
        raise ValueError(f"the stay must be a positive number of steps, got {steps!r}")
    steps = int(steps)
    stays = [s.num_stay for stage in base.stages for s in stage.samplers if isinstance(s, ReachStay)]
    if not stays:
        raise ValueError(f"curriculum {base.name!r} has no reach-stay tasks to lengthen")

    def scaled(sampler: Sampler) -> Sampler:
        if not isinstance(sampler, ReachStay):
            return sampler
        return dataclasses.replace(sampler, num_stay=max(1, round(sampler.num_stay * steps / max(stays))))

    stages = tuple(dataclasses.replace(stage, samplers=tuple(map(scaled, stage.samplers)))
                   for stage in base.stages)
    return Curriculum(f"{base.name}+stay{steps}", stages)


def curriculum(name: str) -> Curriculum:
    """Look up a curriculum by name ("deepltl/letter", "deepltl/zone", "genz/letter", "genz/zone")."""
    if name not in CURRICULA:
        close = difflib.get_close_matches(str(name), list(CURRICULA), n=3)
        hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
        raise ValueError(f"unknown curriculum {name!r}.{hint} Known: {', '.join(CURRICULA)}")
    return CURRICULA[name]


@struct.dataclass
class CurriculumState:
    """Attributes:
    stage: int32[], current stage index.
    task_success: float32[K], last measured success per enumerated task of this stage
        (K = the largest enumeration of the curriculum; unused slots stay 0).
    finished: bool[], the last stage's threshold was met (training does not stop on it).
    """

    stage: jax.Array
    task_success: jax.Array
    finished: jax.Array


class CurriculumSampler:
    """Jittable sampling and stage advancement for one curriculum over P propositions.

    `sample` draws one sequence; `sample_batch(keys, state, current)` is it jitted over a batch
    of keys (shared state and current assignment); `update` advances the stage.
    """

    def __init__(self, curriculum: Curriculum, num_props: int, max_len: int | None = None,
                 twins: np.ndarray | None = None):
        if not isinstance(num_props, int) or num_props < 2:
            raise ValueError(f"num_props must be an int >= 2, got {num_props!r}")
        if twins is not None and (np.shape(twins) != (num_props, num_props)
                                  or not (np.asarray(twins) == np.asarray(twins).T).all()
                                  or np.diagonal(twins).any()):
            raise ValueError(f"twins must be a symmetric bool[{num_props}, {num_props}] with a "
                             f"false diagonal (`specs.twin_matrix`), got shape {np.shape(twins)}")
        self.curriculum = curriculum
        self.num_props = num_props
        self.twins = None if twins is None else np.asarray(twins, bool)
        self.max_len = curriculum.max_len if max_len is None else max_len
        if self.max_len < curriculum.max_len:
            raise ValueError(
                f"max_len={max_len} < {curriculum.max_len} needed by {curriculum.name}"
            )
        for stage in curriculum.stages:
            for sampler in stage.samplers:
                self._check(sampler)
        self.tasks = tuple(self._enumerate(stage) for stage in curriculum.stages)
        sizes = [_num_tasks(t) for t in self.tasks if t is not None]
        self.num_slots = max(sizes, default=1)
        self.sample_batch = jax.jit(jax.vmap(self.sample, in_axes=(0, None, None)))

    def _check(self, sampler: Sampler) -> None:
        """Trace the key-driven sampler once: it validates the static settings."""
        key = jax.random.key(0)
        if isinstance(sampler, ReachStay):
            jax.eval_shape(
                lambda k: seqs.sample_reach_stay(
                    k, self.num_props, sampler.num_stay, sampler.num_avoid, self.max_len
                ),
                key,
            )
        elif isinstance(sampler, ReachAvoid):
            jax.eval_shape(
                lambda k: seqs.sample_reach_avoid(
                    k,
                    self.num_props,
                    sampler.depth,
                    sampler.num_reach,
                    sampler.num_avoid,
                    self.max_len,
                ),
                key,
            )

    def _enumerate(self, stage: Stage):
        s = stage.samplers[0]
        if isinstance(s, AllReach):
            return seqs.all_reach_tasks(self.num_props, s.depth, self.max_len)
        if isinstance(s, AllReachAvoid):
            return seqs.all_reach_avoid_tasks(self.num_props, s.depth, self.max_len, self.twins)
        if isinstance(s, GenZSubgoals):
            return seqs.genz_tasks(self.num_props, s.max_avoid)
        return None

    def init(self) -> CurriculumState:
        return CurriculumState(
            stage=jnp.int32(0),
            task_success=jnp.zeros(self.num_slots, jnp.float32),
            finished=jnp.bool_(False),
        )

    def sample(
        self, key: jax.Array, state: CurriculumState, current: jax.Array | None = None
    ) -> tuple[seqs.ReachAvoidSequence, jax.Array]:
        """Draw a sequence from the current stage.

        Args:
            key: PRNG key.
            state: the curriculum state.
            current: bool[P], propositions true now (GenZ stages exclude subgoals it already
                meets); default none.

        Returns:
            The sequence (padded to `max_len`) and the task index in the stage's enumeration,
            int32[] (-1 for sampled stages).
        """
        if current is None:
            current = jnp.zeros(self.num_props, bool)
        # One PRNG draw serves every branch (see `sequences.reach_avoid_from_uniform`).
        u = jax.random.uniform(key, (1 + self.max_len * 4 * self.num_props,))
        branches = [
            (lambda v, s, c, i=i: self._sample_stage(i, v, s, c))
            for i in range(len(self.curriculum.stages))
        ]
        return jax.lax.switch(state.stage, branches, u, state.task_success, current)

    def _sample_stage(self, index, u, task_success, current):
        stage, tasks = self.curriculum.stages[index], self.tasks[index]
        sampler = stage.samplers[0]
        if isinstance(sampler, GenZSubgoals):
            return seqs.genz_from_uniform(u[0], tasks, current, self.max_len)
        if stage.is_enumerated:
            success = task_success[: _num_tasks(tasks)]
            logits = (
                jnp.zeros_like(success)
                if stage.temperature is None
                else (-success / stage.temperature)
            )
            return seqs.task_from_uniform(u[0], tasks, logits)
        pick = jnp.searchsorted(jnp.cumsum(jnp.asarray(stage.probs)), u[0] * sum(stage.probs))
        pick = jnp.minimum(pick, len(stage.samplers) - 1)
        rest = u[1:].reshape(self.max_len, 4, self.num_props)
        parts = [lambda r, s=s: self._sample_random(s, r) for s in stage.samplers]
        return jax.lax.switch(pick, parts, rest), jnp.int32(-1)

    def _sample_random(self, sampler: Sampler, u: jax.Array) -> seqs.ReachAvoidSequence:
        if isinstance(sampler, ReachStay):
            return seqs.reach_stay_from_uniform(
                u.reshape(-1, self.num_props)[:3],
                self.num_props,
                sampler.num_stay,
                sampler.num_avoid,
                self.max_len,
                self.twins,
            )
        return seqs.reach_avoid_from_uniform(
            u, self.num_props, sampler.depth, sampler.num_reach, sampler.num_avoid, self.max_len,
            self.twins,
        )

    def sample_formulas(
        self, seed: int, stage: int, num: int, propositions: Sequence[str]
    ) -> list[str]:
        """Host side: `num` formulas of one stage, fixed by `seed` (`sequence_to_formula`).

        For formula-conditioned methods trained on these curricula; reach-stay tasks become
        `!K U G p`.
        """
        if len(propositions) != self.num_props:
            raise ValueError(f"need {self.num_props} propositions, got {tuple(propositions)}")
        if not 0 <= stage < len(self.curriculum.stages):
            raise ValueError(f"stage must be in 0..{len(self.curriculum.stages) - 1}, got {stage}")
        keys = jax.random.split(jax.random.key(seed), num)
        state = self.init().replace(stage=jnp.int32(stage))
        batch, _ = jax.device_get(self.sample_batch(keys, state, None))
        return [
            sequence_to_formula(jax.tree_util.tree_map(lambda x, i=i: x[i], batch), propositions)
            for i in range(num)
        ]

    def update(
        self,
        state: CurriculumState,
        task_id: jax.Array,
        finished: jax.Array,
        success: jax.Array,
    ) -> CurriculumState:
        """Advance the curriculum from one rollout's episodes (pure, jittable).

        Args:
            state: the curriculum state the episodes were sampled under.
            task_id: int32[N], task index per episode from `sample` (-1 = sampled stage).
            finished: bool[N], the episode ended during the rollout.
            success: bool[N], it ended in success.

        Returns:
            The new state: same stage with refreshed per-task success, or the next stage
            (per-task success reset) when the aggregate reached the threshold.
        """
        num = self.num_slots
        enumerated = finished & (task_id >= 0)
        slot = jnp.where(enumerated, task_id, num)
        count = jax.ops.segment_sum(enumerated.astype(jnp.float32), slot, num + 1)[:num]
        wins = jax.ops.segment_sum((enumerated & success).astype(jnp.float32), slot, num + 1)[:num]
        seen = count > 0
        rate = wins / jnp.maximum(count, 1.0)
        single = finished & (task_id < 0)
        num_tasks = seen.sum() + single.sum()
        mean = (jnp.where(seen, rate, 0.0).sum() + (single & success).sum()) / jnp.maximum(
            num_tasks, 1
        )
        lowest = jnp.minimum(
            jnp.where(seen, rate, jnp.inf).min(), jnp.where(single, success, jnp.inf).min()
        )
        stages = self.curriculum.stages
        threshold = jnp.asarray([jnp.inf if s.threshold is None else s.threshold for s in stages])
        use_min = jnp.asarray([s.aggregate == "min" for s in stages])
        value = jnp.where(use_min[state.stage], lowest, mean)
        passed = (num_tasks > 0) & (value >= threshold[state.stage])
        last = len(stages) - 1
        task_success = jnp.where(seen, rate, state.task_success)
        return CurriculumState(
            stage=jnp.where(passed, jnp.minimum(state.stage + 1, last), state.stage).astype(
                jnp.int32
            ),
            task_success=jnp.where(passed, 0.0, task_success).astype(jnp.float32),
            finished=state.finished | (passed & (state.stage == last)),
        )


def _num_tasks(tasks) -> int:
    return tasks.reach.shape[0]
