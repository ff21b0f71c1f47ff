"""The world families of the benchmark as data: one record per family says everything the
benchmark knows about it (which IDs, horizon, the paper's suites, the reference PPO shape and
discount, the rollout shape and training reset bank per device kind, the task sources of each
method, the shipped formula encoders). Worlds carry their family's name as `env.family`; nothing
parses env IDs.

This module is pure data and imports nothing from the package, so that every layer may read it.
Adding a family means one record here (or `register_family` at run time) and its env module.
"""

from __future__ import annotations

import dataclasses
import difflib
import fnmatch
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

#: infinite-horizon suites run this many finite horizons (LetterWorld 750, Zone 10,000, Arm 2,000):
#: the smallest round factor consistent with the paper's tables (its Zone persistence figures
#: count more visits than 1,000 steps hold)
INFINITE_HORIZON_FACTOR = 10
#: env steps of a training run unless told otherwise: the paper's 15M on an accelerator, a
#: budget of minutes on a CPU
DEFAULT_TOTAL_STEPS = {"cpu": 200_000, "gpu": 15_000_000}


def _kind(device_kind: str) -> str:
    """"cpu", or "gpu" for any accelerator platform name."""
    return "cpu" if device_kind == "cpu" else "gpu"


def default_total_steps(device_kind: str) -> int:
    """Env steps of a training run on "cpu" or any accelerator platform name."""
    return DEFAULT_TOTAL_STEPS[_kind(device_kind)]


def _frozen(mapping: Mapping[str, Any]) -> Mapping[str, Any]:
    return MappingProxyType(dict(mapping))


@dataclasses.dataclass(frozen=True)
class WorldFamily:
    """One world family.

    Attributes:
        name: the value of `env.family` for its worlds ("letter", "zone", ...).
        title: the paper's name for it.
        id_patterns: `fnmatch` patterns of its registered IDs (for listings and the grid only).
        horizon: steps of a finite-horizon episode; infinite suites run
            `horizon * INFINITE_HORIZON_FACTOR`.
        suites: the paper's evaluation suites of the family; a world takes those whose
            propositions are its own (`suites_for`), so one family may hold several variants.
        ppo: the reference PPO shape, discount and entropy shared by the baselines.
        rollout: the training rollout shape per device kind ("cpu", "gpu"), per seed.
        task_sources: per method, the curriculum (a name of `specs.CURRICULA`) or the original
            formula sampler it trains on in this family.
        formula_encoder: the family whose shipped pretrained formula encoders (RAD-Embeddings,
            LTL2Action) this family uses; None when there is none.
        trainable: whether single-agent training applies (multi-agent worlds are evaluated with
            the coordinator over single-agent policies).
        map_bank: per device kind ("cpu", "gpu"), the exactly sampled layouts in the bank that
            training resets draw from (`env.with_map_bank`); empty: exact resets.
        reference_env: the family's standard world (its alphabet and propositions are the
            family's: pretrained formula encoders are made on it).
    """

    name: str
    title: str
    id_patterns: tuple[str, ...]
    horizon: int
    suites: tuple[str, ...]
    ppo: Mapping[str, Any]
    rollout: Mapping[str, Mapping[str, int]]
    task_sources: Mapping[str, str] = dataclasses.field(default_factory=dict)
    formula_encoder: str | None = None
    trainable: bool = True
    map_bank: Mapping[str, int] = dataclasses.field(default_factory=dict)
    reference_env: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "ppo", _frozen(self.ppo))
        object.__setattr__(self, "rollout", _frozen({k: _frozen(v) for k, v in self.rollout.items()}))
        object.__setattr__(self, "task_sources", _frozen(self.task_sources))
        object.__setattr__(self, "map_bank", _frozen(self.map_bank))

    @property
    def infinite_horizon(self) -> int:
        return self.horizon * INFINITE_HORIZON_FACTOR

    def matches(self, env_id: str) -> bool:
        """Whether `env_id` is one of this family's IDs."""
        return any(fnmatch.fnmatchcase(env_id, p) for p in self.id_patterns)

    def rollout_shape(self, device_kind: str) -> dict[str, int]:
        """`num_envs`, `num_steps`, `num_minibatches` per seed on "cpu" or "gpu" (any accelerator)."""
        return dict(self.rollout[_kind(device_kind)])

    def map_bank_size(self, device_kind: str) -> int:
        """Layouts in the training reset bank on "cpu" or any accelerator (0: exact resets)."""
        return int(self.map_bank.get(_kind(device_kind), 0))


_ZONE_PPO = {"num_envs": 16, "num_steps": 4096, "num_minibatches": 32, "gamma": 0.998,
             "ent_coef": 0.003}
# an accelerator takes 512 x 128 = 65,536 samples per update in minibatches of 2,048, the
# reference's update size (16 x 4096); a CPU 16 x 128 (docs/fidelity.md, training shape)
_WIDE = {"cpu": {"num_envs": 16, "num_steps": 128, "num_minibatches": 8},
         "gpu": {"num_envs": 512, "num_steps": 128, "num_minibatches": 32}}

LETTER = WorldFamily(
    name="letter",
    title="LetterWorld",
    id_patterns=("LetterLTL*",),
    horizon=75,
    suites=("letter/finite/ind", "letter/finite/ood", "letter/infinite/rsp", "letter/infinite/rec"),
    ppo={"num_envs": 16, "num_steps": 128, "num_minibatches": 8, "gamma": 0.94, "ent_coef": 0.01},
    rollout={"cpu": {"num_envs": 16, "num_steps": 128, "num_minibatches": 8},
             "gpu": {"num_envs": 256, "num_steps": 128, "num_minibatches": 8}},
    task_sources={"genz": "genz/letter", "deepltl": "deepltl/letter",
                  "ltl2action": "deepltl/letter", "rad": "deepltl/letter"},
    formula_encoder="letter",
    # 4,096 exact maps take seconds on a CPU (65,536 minutes there, a second on an accelerator)
    map_bank={"cpu": 4096, "gpu": 65536},
    reference_env="LetterLTL0-v0",
)

ZONE = WorldFamily(
    name="zone",
    title="ZoneEnv",
    id_patterns=tuple(f"{robot}LTL[012]{vision}-*" for robot in ("Point", "Car", "Ant")
                      for vision in ("", "Vision")),
    horizon=1000,
    suites=("zone/finite/ind", "zone/finite/ood", "zone/infinite/rsp", "zone/infinite/rec",
            "zone/infinite/per"),
    ppo=_ZONE_PPO,
    rollout=_WIDE,
    task_sources={"genz": "genz/zone", "deepltl": "deepltl/zone",
                  "ltl2action": "deepltl/zone", "rad": "deepltl/zone"},
    formula_encoder="zone",
    # under `vmap` an exact layout is computed for every world at every step: a CPU rollout took
    # 10x (PointLTL0) to 400x (PointLTL2) the bank's (docs/fidelity.md); 512 take seconds
    # (PointLTL2 ~40 s) on a CPU
    map_bank={"cpu": 512, "gpu": 65536},
    reference_env="PointLTL0-v0",
)

ARM = WorldFamily(
    name="arm",
    title="Panda arm",
    id_patterns=("PandaLTLReach*",),
    horizon=200,
    # grippers-only worlds (mode 0) take the first five, grippers-and-arm worlds the last two
    suites=("arm_grippers/finite/ind", "arm_grippers/finite/ood", "arm_grippers/infinite/rsp",
            "arm_grippers/infinite/rec", "arm_grippers/infinite/per",
            "arm_grippers_arm/finite/ind", "arm_grippers_arm/finite/ood"),
    ppo={"num_envs": 16, "num_steps": 1024, "num_minibatches": 8, "gamma": 0.99,
         "ent_coef": 0.003},
    # the Zone update (65,536 samples, minibatches of 2,048) from 8x the arms for 1/8 the steps:
    # an arm step's latency (~116 ms for 2,560 arms on an H200) bounds a 128-step rollout
    rollout={"cpu": _WIDE["cpu"],
             "gpu": {"num_envs": 4096, "num_steps": 16, "num_minibatches": 32}},
    task_sources={"genz": "genz/zone", "deepltl": "deepltl/zone",
                  "ltl2action": "Until_1_2_1_1", "rad": "rad"},
    formula_encoder="zone",
    # an exact layout (rejection sampling) costs ~100 ms per arm on a CPU, ~120x a world step:
    # computed for every arm at every step, it bounded training (docs/fidelity.md); 512 take
    # about a minute on a CPU
    map_bank={"cpu": 512, "gpu": 65536},
    reference_env="PandaLTLReach0Joints-v0",
)

MULTI_AGENT_ZONE = WorldFamily(
    name="multi_agent_zone",
    title="ZoneEnv, multi-agent",
    id_patterns=("PointLTL0MA*",),
    horizon=1000,
    suites=("multi_agent_zone/finite/indep", "multi_agent_zone/finite/coop",
            "multi_agent_zone/finite/mix", "multi_agent_zone/infinite/rsp",
            "multi_agent_zone/infinite/rec", "multi_agent_zone/infinite/per"),
    ppo=_ZONE_PPO,
    rollout=_WIDE,
    trainable=False,
    reference_env="PointLTL0MA2-v0",
)

_FAMILIES: dict[str, WorldFamily] = {f.name: f for f in (LETTER, ZONE, ARM, MULTI_AGENT_ZONE)}


def encoder_name(family: str, alphabet: Any, per_symbol: bool) -> str | None:
    """The shipped formula encoder a world of `family` reads: the family's `formula_encoder`, or
    `<family>_overlap` for an encoder over alphabet symbols (`per_symbol`, RAD-Embeddings' DFAs)
    when the world's labels (`alphabet`, bool[A, P]) can hold several propositions at once. A
    family that borrows another's encoder (the arm, Zone's) reads it where labels do not overlap
    and has its own overlap encoder where they do (the grippers-and-arm alphabet)."""
    rows, props = len(alphabet), len(alphabet[0])
    if per_symbol and props > 1 and rows > props + 1:
        return f"{family}_overlap"
    return get(family).formula_encoder if family in _FAMILIES else family


def register_family(record: WorldFamily) -> None:
    """Add a family (its worlds set `env.family = record.name`)."""
    if record.name in _FAMILIES:
        raise ValueError(f"world family {record.name!r} is already registered")
    _FAMILIES[record.name] = record


def unregister_family(name: str) -> None:
    """Remove a family added by `register_family`."""
    if name in (LETTER.name, ZONE.name, ARM.name, MULTI_AGENT_ZONE.name):
        raise ValueError(f"the built-in family {name!r} cannot be removed")
    _FAMILIES.pop(name, None)


def list_families() -> list[str]:
    return list(_FAMILIES)


def get(name: str) -> WorldFamily:
    """The record of a family by name, with a clear error for an unknown one."""
    if name not in _FAMILIES:
        close = difflib.get_close_matches(str(name), list(_FAMILIES), n=3)
        hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
        raise ValueError(f"unknown world family {name!r}.{hint} Known: {', '.join(_FAMILIES)}")
    return _FAMILIES[name]


def of(world: Any) -> WorldFamily:
    """The record of a world's family (`world.family`)."""
    name = getattr(world, "family", None)
    if name is None:
        raise ValueError(f"{type(world).__name__} declares no world family (`family` attribute); "
                         f"known families: {', '.join(_FAMILIES)}")
    return get(name)


def name_of(world: Any, family: str | None = None) -> str:
    """`family` if given, else the world's own family name (`world.family`)."""
    return family if family is not None else of(world).name


def resolve(family: WorldFamily | str | None, world: Any = None) -> WorldFamily:
    """A family record from a record, a name, or (None) the world's own family."""
    if isinstance(family, WorldFamily):
        return family
    if family is None:
        return of(world)
    return get(family)


def family_of_id(env_id: str) -> WorldFamily:
    """The family whose ID patterns match `env_id` (listings and the grid; code that has a world
    reads `world.family` instead)."""
    found = [f for f in _FAMILIES.values() if f.matches(env_id)]
    if len(found) != 1:
        raise ValueError(f"env ID {env_id!r} matches {len(found)} world families "
                         f"({', '.join(f.name for f in found) or 'none'})")
    return found[0]
