"""Reach-avoid training sequences: jittable samplers and task enumerations.

A sequence is what DeepLTL / GenZ-LTL train on instead of a formula: pairs (reach_i, avoid_i)
over propositions, worked through in order. Step i is done when a reach_i proposition holds, and
fails when an avoid_i proposition holds (or, with `avoid_empty[i]`, when none holds). An epsilon
step is done by the agent's epsilon action instead. The last pair is repeated `repeat_last` more
times (reach-stay tasks).

Every sampler here is a pure function of a key and static settings (Python ints / tuples), so it
runs under `jit` and `vmap`; sequences are padded with empty pairs to a static `max_len`.

Satisfiability is by construction under the "at most one proposition" alphabet: reach_i never
meets avoid_i, consecutive reach sets are disjoint, and avoid_i excludes reach_{i-1}, so the walk
r_1, r_2, ... (one reach proposition per step) completes every sequence. Where a world's
propositions can name one object (the grippers-and-arm Arm's `arm_c` and `grippers_c`: the hand
touches a sphere the fingers reach), `twins` (bool[P, P], symmetric) keeps each reach's and
previous reach's twins out of avoid_i as well, and a stay's twin out of both pairs of a
reach-stay task (whose task still counts the twin alone as leaving the stay).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

Range = tuple[int, int]


@struct.dataclass
class ReachAvoidSequence:
    """One reach-avoid sequence (or a batch, with leading axes), padded to `L` pairs.

    Attributes:
        reach: bool[L, P], propositions of which any completes pair i.
        avoid: bool[L, P], propositions of which any violates while pair i is current.
        avoid_empty: bool[L], the no-proposition assignment also violates (reach-stay).
        epsilon: bool[L], pair i is completed by the epsilon action, not by a proposition.
        length: int32[], number of real pairs (the rest is padding).
        repeat_last: int32[], extra repetitions of the last real pair.
    """

    reach: jax.Array
    avoid: jax.Array
    avoid_empty: jax.Array
    epsilon: jax.Array
    length: jax.Array
    repeat_last: jax.Array

    @property
    def max_len(self) -> int:
        return self.reach.shape[-2]


@struct.dataclass
class GenZTasks:
    """The enumerated one-step subgoals of GenZ-LTL: reach one proposition, avoid a subset.

    Attributes:
        reach: int32[K], the proposition to reach.
        avoid: bool[K, P], the avoid set (never containing `reach`).
    """

    reach: jax.Array
    avoid: jax.Array

    @property
    def num_tasks(self) -> int:
        return self.reach.shape[0]


def _check_range(name: str, value: Range) -> None:
    if (
        not isinstance(value, tuple)
        or len(value) != 2
        or not all(isinstance(v, int) for v in value)
        or not 0 <= value[0] <= value[1]
    ):
        raise ValueError(
            f"{name} must be a (low, high) tuple of ints with 0 <= low <= high, got {value!r}"
        )


def _check_len(depth: int, max_len: int) -> None:
    if not isinstance(depth, int) or depth < 1:
        raise ValueError(f"depth must be a positive int, got {depth!r}")
    if max_len < depth:
        raise ValueError(f"max_len={max_len} cannot hold a sequence of {depth} pairs")


def _random_subset(scores: jax.Array, allowed: jax.Array, size: jax.Array) -> jax.Array:
    """A uniformly random subset of `min(size, allowed.sum())` allowed entries, as bool[P].

    `scores` are i.i.d. uniforms, one per entry; the subset is the `size` smallest allowed.
    """
    scores = jnp.where(allowed, scores, 2.0)
    # Rank by pairwise comparison: P is small, and XLA compiles this far faster than a sort.
    rank = jnp.sum(scores[None, :] < scores[:, None], axis=1)
    return allowed & (rank < size)


def twin_matrix(propositions: Sequence[str], same_object: Sequence[tuple[str, str]]) -> np.ndarray:
    """bool[P, P], symmetric: True where two of `propositions` name one object (`same_object`,
    pairs of names, e.g. a world's `("arm_blue", "grippers_blue")`)."""
    index = {p: i for i, p in enumerate(propositions)}
    twins = np.zeros((len(propositions), len(propositions)), bool)
    for a, b in same_object:
        if a not in index or b not in index or a == b:
            raise ValueError(f"same-object pair {(a, b)!r}: need two of {tuple(propositions)}")
        twins[index[a], index[b]] = twins[index[b], index[a]] = True
    return twins


def _twins_of(props: jax.Array, twins: np.ndarray | None) -> jax.Array:
    """bool[P]: the propositions that are a twin of some proposition in `props` (bool[P])."""
    if twins is None:
        return jnp.zeros_like(props)
    return jnp.any(props[:, None] & jnp.asarray(twins, bool), axis=0)


def _size(u: jax.Array, bounds: Range) -> jax.Array:
    """A uniform integer in the inclusive `bounds`, from a uniform u in [0, 1)."""
    return jnp.minimum(bounds[0] + jnp.floor(u * (bounds[1] - bounds[0] + 1)), bounds[1])


def _pad(rows: list[jax.Array], max_len: int, fill_shape: tuple[int, ...]) -> jax.Array:
    pad = [jnp.zeros(fill_shape, bool)] * (max_len - len(rows))
    return jnp.stack(rows + pad)


def sample_reach_avoid(
    key: jax.Array,
    num_props: int,
    depth: int,
    num_reach: Range,
    num_avoid: Range,
    max_len: int,
) -> ReachAvoidSequence:
    """DeepLTL's random reach-avoid sequence of `depth` pairs (`sample_reach_avoid`).

    Each pair draws |reach| uniformly from `num_reach` and |avoid| from `num_avoid`; reach comes
    from the propositions outside the previous reach, avoid from those outside this and the
    previous reach (sizes shrink when too few are left).

    Args:
        key: PRNG key.
        num_props: P, static.
        depth: number of pairs, static.
        num_reach: inclusive (low, high) reach-set size, static.
        num_avoid: inclusive (low, high) avoid-set size, static.
        max_len: L >= depth, static padding length.

    Returns:
        A `ReachAvoidSequence` with `length = depth`, `repeat_last = 0`.
    """
    _check_len(depth, max_len)
    _check_range("num_reach", num_reach)
    _check_range("num_avoid", num_avoid)
    if num_reach[0] < 1:
        raise ValueError(f"num_reach must start at 1 or more, got {num_reach!r}")
    u = jax.random.uniform(key, (depth, 4, num_props))
    return reach_avoid_from_uniform(u, num_props, depth, num_reach, num_avoid, max_len)


def reach_avoid_from_uniform(
    u: jax.Array, num_props: int, depth: int, num_reach: Range, num_avoid: Range, max_len: int,
    twins: np.ndarray | None = None,
) -> ReachAvoidSequence:
    """`sample_reach_avoid` driven by given uniforms u: float32[>= depth, 4, P] in [0, 1);
    `twins` (bool[P, P] or None) keeps the reach's and previous reach's twins out of avoid.

    Every sampler has such a form so that a caller (the curriculum) makes one PRNG draw for
    all of its branches: each threefry call costs seconds of XLA compile time on CPU.
    """
    prev_reach = jnp.zeros(num_props, bool)
    reaches, avoids = [], []
    for i in range(depth):
        reach = _random_subset(u[i, 1], ~prev_reach, _size(u[i, 0, 0], num_reach))
        kept_out = reach | prev_reach | _twins_of(reach | prev_reach, twins)
        avoid = _random_subset(u[i, 3], ~kept_out, _size(u[i, 2, 0], num_avoid))
        reaches.append(reach)
        avoids.append(avoid)
        prev_reach = reach
    return ReachAvoidSequence(
        reach=_pad(reaches, max_len, (num_props,)),
        avoid=_pad(avoids, max_len, (num_props,)),
        avoid_empty=jnp.zeros(max_len, bool),
        epsilon=jnp.zeros(max_len, bool),
        length=jnp.int32(depth),
        repeat_last=jnp.int32(0),
    )


def sample_reach_stay(
    key: jax.Array, num_props: int, num_stay: int, num_avoid: Range, max_len: int
) -> ReachAvoidSequence:
    """DeepLTL's reach-stay task: (epsilon, avoid K), then stay in p for `num_stay` + 1 steps.

    p is uniform; K is a uniform subset of the other propositions with |K| drawn from
    `num_avoid`. The stay pair avoids every other proposition and the empty assignment, so once
    the agent takes the epsilon action it must be in p at every following step.

    Returns:
        A `ReachAvoidSequence` with `length = 2`, `repeat_last = num_stay`.
    """
    _check_len(2, max_len)
    _check_range("num_avoid", num_avoid)
    return reach_stay_from_uniform(
        jax.random.uniform(key, (3, num_props)), num_props, num_stay, num_avoid, max_len
    )


def reach_stay_from_uniform(
    u: jax.Array, num_props: int, num_stay: int, num_avoid: Range, max_len: int,
    twins: np.ndarray | None = None,
) -> ReachAvoidSequence:
    """`sample_reach_stay` driven by given uniforms u: float32[>= 3, P] in [0, 1); `twins`
    (bool[P, P] or None): the stay proposition's twins are in neither pair's avoid set (a
    task built from the sequence, `tasks.sources.SequenceSource.from_sequence`, still counts
    the twin alone as leaving the stay)."""
    prop = jnp.minimum(jnp.floor(u[0, 0] * num_props), num_props - 1).astype(jnp.int32)
    stay = jnp.arange(num_props) == prop
    kept_out = stay | _twins_of(stay, twins)
    avoid_first = _random_subset(u[2], ~kept_out, _size(u[1, 0], num_avoid))
    empty = jnp.zeros(num_props, bool)
    flags = jnp.zeros(max_len, bool)
    return ReachAvoidSequence(
        reach=_pad([empty, stay], max_len, (num_props,)),
        avoid=_pad([avoid_first, ~kept_out], max_len, (num_props,)),
        avoid_empty=flags.at[1].set(True),
        epsilon=flags.at[0].set(True),
        length=jnp.int32(2),
        repeat_last=jnp.int32(num_stay),
    )


def _stack_tasks(chains: list[list[tuple[int, int | None]]], num_props: int, max_len: int):
    """Host enumeration -> stacked `ReachAvoidSequence` of K single-proposition chains."""
    reach = np.zeros((len(chains), max_len, num_props), bool)
    avoid = np.zeros_like(reach)
    for k, chain in enumerate(chains):
        for i, (r, a) in enumerate(chain):
            reach[k, i, r] = True
            if a is not None:
                avoid[k, i, a] = True
    num = len(chains)
    depth = len(chains[0])
    return ReachAvoidSequence(
        reach=jnp.asarray(reach),
        avoid=jnp.asarray(avoid),
        avoid_empty=jnp.zeros((num, max_len), bool),
        epsilon=jnp.zeros((num, max_len), bool),
        length=jnp.full((num,), depth, jnp.int32),
        repeat_last=jnp.zeros((num,), jnp.int32),
    )


def all_reach_tasks(num_props: int, depth: int, max_len: int) -> ReachAvoidSequence:
    """Every chain of `depth` single propositions with consecutive ones distinct, no avoid.

    Returns:
        A batch of K = P * (P-1)^(depth-1) sequences (leading axis K), in lexicographic order.
    """
    _check_len(depth, max_len)
    chains = [
        [(r, None) for r in seq]
        for seq in itertools.product(range(num_props), repeat=depth)
        if all(a != b for a, b in itertools.pairwise(seq))
    ]
    return _stack_tasks(chains, num_props, max_len)


def all_reach_avoid_tasks(num_props: int, depth: int, max_len: int,
                          twins: np.ndarray | None = None) -> ReachAvoidSequence:
    """Every chain of (reach p_i, avoid q_i) with q_i != p_i, p_i != p_{i-1}, q_i != p_{i-1}
    (and, with `twins`, bool[P, P], q_i no twin of p_i or p_{i-1}).

    Returns:
        A batch of K = P(P-1) * ((P-1)(P-2))^(depth-1) sequences (leading axis K; fewer with
        twins).
    """
    _check_len(depth, max_len)
    twin = np.zeros((num_props, num_props), bool) if twins is None else np.asarray(twins, bool)
    pairs = [(r, a) for r in range(num_props) for a in range(num_props)
             if a != r and not twin[r, a]]
    chains = [
        list(chain)
        for chain in itertools.product(pairs, repeat=depth)
        if all(nxt[0] != prev[0] and nxt[1] != prev[0] and not twin[prev[0], nxt[1]]
               for prev, nxt in itertools.pairwise(chain))
    ]
    if not chains:
        raise ValueError(f"no reach-avoid chain of depth {depth} over {num_props} propositions "
                         "keeps every avoid apart from its reach's twins")
    return _stack_tasks(chains, num_props, max_len)


def sample_task(
    key: jax.Array, tasks: ReachAvoidSequence, logits: jax.Array
) -> tuple[ReachAvoidSequence, jax.Array]:
    """Draw one enumerated task with probability softmax(`logits`).

    Args:
        key: PRNG key.
        tasks: a batch of K sequences.
        logits: float32[K]; DeepLTL's explicit stages use -success / temperature.

    Returns:
        The drawn sequence and its index, int32[].
    """
    return task_from_uniform(jax.random.uniform(key), tasks, logits)


def task_from_uniform(
    u: jax.Array, tasks: ReachAvoidSequence, logits: jax.Array
) -> tuple[ReachAvoidSequence, jax.Array]:
    """`sample_task` by inverting the CDF of softmax(`logits`) at the uniform u: float32[]."""
    cdf = jnp.cumsum(jax.nn.softmax(logits))
    index = jnp.searchsorted(cdf, u * cdf[-1], side="right")
    index = jnp.minimum(index, logits.shape[0] - 1).astype(jnp.int32)
    return jax.tree_util.tree_map(lambda leaf: leaf[index], tasks), index


def genz_tasks(num_props: int, max_avoid: int = 3) -> GenZTasks:
    """Every GenZ-LTL subgoal: reach p, avoid a subset of size 0..`max_avoid` of the others.

    With P = 12, max_avoid = 3 that is 12 * 232 = 2784 tasks (LetterWorld); with P = 4 every
    subset of the other 3, 32 tasks (ZoneEnv).
    """
    if num_props < 1 or max_avoid < 0:
        raise ValueError(f"need num_props >= 1 and max_avoid >= 0, got {num_props}, {max_avoid}")
    reach, avoid = [], []
    for r in range(num_props):
        others = [p for p in range(num_props) if p != r]
        for size in range(min(max_avoid, len(others)) + 1):
            for subset in itertools.combinations(others, size):
                reach.append(r)
                avoid.append(np.isin(np.arange(num_props), subset))
    return GenZTasks(reach=jnp.asarray(reach, jnp.int32), avoid=jnp.asarray(np.stack(avoid)))


def sample_genz_subgoal(
    key: jax.Array, tasks: GenZTasks, current: jax.Array, max_len: int = 1
) -> tuple[ReachAvoidSequence, jax.Array]:
    """GenZ-LTL's subgoal draw: uniform over the tasks that the current assignment leaves open.

    A task is excluded when the current assignment already satisfies its reach or lies in its
    avoid set (GenZ resamples after each reach, where the agent still stands on the old goal).

    Args:
        key: PRNG key.
        tasks: `genz_tasks(P, ...)`.
        current: bool[P], the propositions true now (all False at reset).
        max_len: L, static padding length (1 for a single pair).

    Returns:
        A one-pair `ReachAvoidSequence` and the task index, int32[].
    """
    return genz_from_uniform(jax.random.uniform(key), tasks, current, max_len)


def genz_from_uniform(
    u: jax.Array, tasks: GenZTasks, current: jax.Array, max_len: int = 1
) -> tuple[ReachAvoidSequence, jax.Array]:
    """`sample_genz_subgoal` driven by a uniform u: float32[] in [0, 1)."""
    num_props = tasks.avoid.shape[-1]
    is_open = ~current[tasks.reach] & ~jnp.any(tasks.avoid & current, axis=-1)
    # The n-th open task for a uniform n: exact, and cheaper than a K-way categorical.
    num_open = jnp.cumsum(is_open)
    chosen = jnp.minimum(jnp.floor(u * num_open[-1]), num_open[-1] - 1)
    index = jnp.searchsorted(num_open, chosen, side="right").astype(jnp.int32)
    reach = jax.nn.one_hot(tasks.reach[index], num_props) > 0
    flags = jnp.zeros(max_len, bool)
    sequence = ReachAvoidSequence(
        reach=_pad([reach], max_len, (num_props,)),
        avoid=_pad([tasks.avoid[index]], max_len, (num_props,)),
        avoid_empty=flags,
        epsilon=flags,
        length=jnp.int32(1),
        repeat_last=jnp.int32(0),
    )
    return sequence, index
