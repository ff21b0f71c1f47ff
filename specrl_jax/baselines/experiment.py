"""Train a baseline on any single-agent world and evaluate it on the paper's suites: the pipeline
behind `specrl-jax train`, `specrl-jax run` and `benchmarks/train_baselines.py`.

Seeds follow the paper's protocol: `num_seeds` independent trainings (side by side under
`vmap`), each evaluated with its own seed on `episodes` fresh layouts per spec; tables report the
mean and std over the seeds.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from specrl_jax.baselines import deepltl, gcrl, genz, ltl2action, rad, runs
from specrl_jax.baselines.ppo import env_mesh, make_train
from specrl_jax.envs.registry import make

METHODS = {"genz": genz, "deepltl": deepltl, "ltl2action": ltl2action, "gcrl": gcrl, "rad": rad}
METHOD_NAMES = {"genz": "GenZ-LTL", "deepltl": "DeepLTL", "ltl2action": "LTL2Action",
                "gcrl": "GCRL-LTL", "rad": "RAD-Embeddings"}
LETTER_SUITES = ("letter/finite/ind", "letter/finite/ood", "letter/infinite/rsp", "letter/infinite/rec")
SUCCESS_LEVELS = (0.5, 0.8, 0.9, 0.95, 0.98)


#: env ID prefix -> world family (PPO settings, curricula, default suites)
FAMILIES = {"Letter": "letter", "Point": "zone", "Car": "zone", "Ant": "zone", "Panda": "arm"}
SUITES = {
    "letter": LETTER_SUITES,
    "zone": ("zone/finite/ind", "zone/finite/ood", "zone/infinite/rsp", "zone/infinite/rec",
             "zone/infinite/per"),
    # the grippers-only arm's (mode 0); `suites_for` gives mode 1 its grippers+arm suites
    "arm": ("arm_grippers/finite/ind", "arm_grippers/finite/ood", "arm_grippers/infinite/rsp",
            "arm_grippers/infinite/rec", "arm_grippers/infinite/per"),
}
#: the paper's arm suites by observation mode (the env ID's digit: PandaLTLReach0... / 1...)
ARM_SUITES = {0: SUITES["arm"], 1: ("arm_grippers_arm/finite/ind", "arm_grippers_arm/finite/ood")}


def method_module(name: str):
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; accepted: {', '.join(METHODS)}")
    return METHODS[name]


def method_options_accepted(method: str) -> tuple[str, ...]:
    """The options `method`'s `make_method` takes beyond the world, its params and the family."""
    names = list(inspect.signature(method_module(method).make_method).parameters)
    return tuple(names[3:])


def check_method_options(method: str, options: dict[str, Any] | None) -> None:
    """A ValueError naming the options `method` does not take, and listing the ones it does."""
    unknown = sorted(set(options or {}) - set(method_options_accepted(method)))
    if unknown:
        raise ValueError(f"{METHOD_NAMES[method]} has no option {', '.join(map(repr, unknown))}; "
                         f"accepted: {', '.join(method_options_accepted(method))}")


def make_method(method: str, world: Any, params: Any, world_family: str,
                options: dict[str, Any] | None = None) -> Any:
    """`method`'s `make_method(world, params, world_family, **options)`, its options checked."""
    check_method_options(method, options)
    return method_module(method).make_method(world, params, world_family, **(options or {}))


def family(env_id: str) -> str:
    """The world family of a single-agent env ID ("letter", "zone", "arm")."""
    from specrl_jax.envs.registry import list_envs

    found = [f for prefix, f in FAMILIES.items() if env_id.startswith(prefix)]
    if not found or env_id not in list_envs() or "MA" in env_id.split("-")[0]:
        trainable = [e for e in list_envs() if any(e.startswith(p) for p in FAMILIES) and "MA" not in e]
        raise ValueError(f"cannot train on env {env_id!r}; single-agent IDs: {', '.join(trainable)}")
    return found[0]


def suites_for(env_id: str) -> tuple[str, ...]:
    """The paper's evaluation suites of a single-agent env ID (the arm's depend on its mode)."""
    world_family = family(env_id)
    if world_family == "arm":
        return ARM_SUITES[int(env_id[len("PandaLTLReach")])]
    return SUITES[world_family]


def build(method: str, env_id: str, ppo_overrides: dict[str, Any], map_bank: int | None, key: jax.Array,
          env_options: dict[str, Any] | None = None, method_options: dict[str, Any] | None = None):
    """(world, train params, method object, PPOConfig) for `method` on `env_id` (built with
    `make(env_id, **env_options)`, the method with `make_method(..., **method_options)`);
    `map_bank` (LetterWorld) draws training resets from a bank of that many exactly sampled maps."""
    module = method_module(method)
    check_method_options(method, method_options)  # before the map bank's seconds
    world_family = family(env_id)
    world, params = make(env_id, **(env_options or {}))
    if map_bank and world_family == "letter":
        # wait for the bank here: dispatched asynchronously, it would finish inside training
        params = jax.block_until_ready(world.with_map_bank(key, params, num_maps=map_bank))
    method_obj = module.make_method(world, params, world_family, **(method_options or {}))
    return world, params, method_obj, module.ppo_config(world_family, **ppo_overrides)


def train(method: str, env_id: str, run_dir: str | Path, ppo_overrides: dict[str, Any], num_seeds: int = 1,
          seed: int = 0, map_bank: int | None = 65536, chunk_updates: int = 10,
          log: Callable[[str], None] = print, max_wall_s: float | None = None,
          restart: bool = False, devices: Sequence[Any] | None = None,
          env_options: dict[str, Any] | None = None, method_options: dict[str, Any] | None = None
          ) -> tuple[Any, dict[str, Any]]:
    """Train `num_seeds` runs; returns `(params with a leading seed axis, training summary)`.
    `env_options` are `make`'s overrides of the world (e.g. `{"image_size": 64}`),
    `method_options` the method's `make_method` options (e.g. `{"sampler": "curriculum"}`).
    `restart` discards a run directory's earlier run (else it is resumed if its settings match).
    The env batch is sharded over `devices` (default: every local device; `num_envs` must
    divide by their count), parameters replicated; the result does not depend on the count
    beyond floating-point reduction order."""
    key_bank, key_train = jax.random.split(jax.random.key(seed))
    start = time.perf_counter()
    if map_bank and family(env_id) == "letter":
        log(f"building a bank of {map_bank:,} exactly sampled maps for training resets ...")
    world, _params, method_obj, config = build(method, env_id, ppo_overrides, map_bank, key_bank,
                                               env_options, method_options)
    prepare = getattr(method_module(method), "prepare_training", None)
    if prepare is not None:  # a first phase before PPO (GCRL-LTL's direction primitives)
        method_obj = prepare(method_obj, key_train, config, log)
    setup = time.perf_counter() - start
    log(f"set up {env_id} in {setup:.1f}s; compiling the training step (the first chunk includes it)")
    # Zone worlds: the backend "auto" chose, so that a run does not resume on another
    physics = getattr(getattr(world, "physics", None), "backend", None)
    mesh = env_mesh(list(devices) if devices is not None else None)
    trainer = make_train(config, method_obj, mesh)
    start = time.perf_counter()
    runner = runs.train_in_run_dir(
        trainer, key_train, run_dir, chunk_updates, num_seeds,
        extra_config={"method": method, "env": env_id, "map_bank": map_bank, "seed": seed,
                      **({"env_options": dict(env_options)} if env_options else {}),
                      **({"physics": physics} if physics else {}),
                      **({"method_options": dict(method_options)} if method_options else {})},
        summarise=method_module(method).summarise, log=log, max_wall_s=max_wall_s, restart=restart,
    )
    wall = time.perf_counter() - start
    rows = runs.read_metrics(run_dir)
    params = runner.params
    finish = getattr(method_module(method), "finish_training", None)
    if finish is not None:  # a second phase on the trained policy (GCRL-LTL's value function)
        params = finish(method_obj, params, key_train, config, log)
    params_path = Path(run_dir) / "params.msgpack"
    params_path.write_bytes(serialization.to_bytes(jax.device_get(params)))
    summary = {
        "method": method, "env": env_id, "num_seeds": num_seeds, "ppo": dataclasses.asdict(config),
        "env_steps_per_seed": rows[-1]["env_steps"] if rows else 0,
        "complete": int(runner.update[0]) >= config.num_updates,
        "devices": int(mesh.size),  # the env batch was sharded over this many devices
        "physics": physics,  # Zone worlds
        "setup_s": setup,  # env and map bank, before training
        "wall_s_this_session": wall,
        # every session's steps over every session's training time (rows' clock spans resumes)
        "env_steps_per_s": rows[-1]["env_steps"] * num_seeds / rows[-1]["wall_s"] if rows else 0.0,
        "final_success_rate": rows[-1].get("success_rate") if rows else None,
        "time_to_success": time_to_levels(rows),
    }
    (Path(run_dir) / "train_summary.json").write_text(json.dumps(summary, indent=1))
    return params, summary


def time_to_levels(rows: Sequence[dict[str, Any]], levels: Sequence[float] = SUCCESS_LEVELS) -> dict[str, Any]:
    """First (env steps, wall s) at which the seed-mean training success rate reaches each level."""
    found = {}
    for level in levels:
        hit = next((r for r in rows if r.get("success_rate", 0.0) >= level), None)
        found[str(level)] = None if hit is None else {"env_steps": hit["env_steps"], "wall_s": hit["wall_s"]}
    return found


def make_policy(method: str, world: Any, method_obj: Any, deterministic: bool | None = None,
                world_family: str = "letter", **options: Any):
    """The method's test-time agent; `deterministic` None = the reference's setting (GenZ-LTL
    mode actions; DeepLTL and GCRL-LTL sampled actions on LetterWorld, mode actions on
    ZoneEnv)."""
    module = method_module(method)
    if deterministic is None:
        deterministic = method == "genz" or world_family != "letter"
    return module.make_policy(method_obj.network, world.alphabet, world.obs_kinds,
                              deterministic=deterministic, **options)


def evaluate(method: str, env_id: str, params: Any, suites: Sequence[str], episodes: int,
             log: Callable[[str], None] = print, deterministic: bool | None = None,
             label: str | None = None, horizon: int | None = None,
             env_options: dict[str, Any] | None = None, devices: Sequence[Any] | None = None,
             method_options: dict[str, Any] | None = None, **policy_options: Any) -> list:
    """Evaluate every trained seed (leading axis of `params`, seed i + 1 for entry i) on `suites`
    (`eval.suites.evaluate_suites`: infinite suites over 10 finite horizons unless `horizon`;
    episodes sharded over `devices`, default every local device).
    Returns `SuiteResult`s with one row per trained seed."""
    from specrl_jax.eval.suites import evaluate_suites

    if hasattr(method_module(method), "usable_suites"):  # RAD: co-safe suites only
        suites = method_module(method).usable_suites(suites, log)
    world, env_params = make(env_id, **(env_options or {}))
    world_family = family(env_id)
    method_obj = make_method(method, world, env_params, world_family, method_options)
    if "suites" in inspect.signature(method_module(method).make_policy).parameters:
        policy_options.setdefault("suites", tuple(suites))  # LTL2Action progresses their formulas
    policy = make_policy(method, world, method_obj, deterministic, world_family, **policy_options)
    num_seeds = jax.tree.leaves(params)[0].shape[0]
    return evaluate_suites(
        policy, env_id, world, env_params, suites, episodes, seeds=range(1, num_seeds + 1),
        policy_params=params, params_per_seed=True, horizon=horizon,
        label=label or METHOD_NAMES[method], log=log, devices=devices,
    )


def load_params(method: str, env_id: str, path: str | Path, num_seeds: int,
                env_options: dict[str, Any] | None = None,
                method_options: dict[str, Any] | None = None) -> Any:
    """Read `params.msgpack` written by `train` (leading seed axis), or one seed's parameters
    without that axis (the results store's `params_seed1.msgpack`), returned with it."""
    world, env_params = make(env_id, **(env_options or {}))
    method_obj = make_method(method, world, env_params, family(env_id), method_options)
    # shapes only: running the env's reset and the network's init eagerly takes seconds on a CPU
    obs, _ = jax.eval_shape(method_obj.env.reset, jax.random.key(0), method_obj.init_task_params())
    one_obs = jax.tree.map(lambda x: jax.ShapeDtypeStruct((1, *x.shape), x.dtype), obs)
    one = jax.eval_shape(method_obj.network.init, jax.random.key(0), one_obs)
    if hasattr(method_module(method), "param_shapes"):  # parameters beyond the PPO network's
        one = method_module(method).param_shapes(method_obj, one)
    stored = serialization.msgpack_restore(Path(path).read_bytes())
    leaf = jax.tree.leaves(stored)[0]
    if num_seeds == 1 and np.ndim(leaf) == len(jax.tree.leaves(one)[0].shape):
        single = jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), one)
        return jax.tree.map(lambda x: x[None], serialization.from_state_dict(single, stored))
    template = jax.tree.map(lambda x: np.zeros((num_seeds, *x.shape), x.dtype), one)
    return serialization.from_state_dict(template, stored)


def default_overrides(device_kind: str, total_steps: int | None = None,
                      world_family: str = "letter") -> dict[str, Any]:
    """Training shape. LetterWorld: the reference's 16 x 128 on a CPU; 256 x 128 (minibatch 4096)
    on an accelerator. ZoneEnv / Arm: 16 x 128 on a CPU; on an accelerator 512 x 128 = 65,536
    samples per update in minibatches of 2,048, the reference's update size (16 x 4096). The
    per-sample settings are unchanged (docs/fidelity.md); GenZ-LTL's epochs are capped at 10
    on an accelerator."""
    if device_kind == "cpu":
        shape = {"num_envs": 16, "num_steps": 128, "num_minibatches": 8}
    elif world_family == "letter":
        shape = {"num_envs": 256, "num_steps": 128, "num_minibatches": 8}
    else:
        shape = {"num_envs": 512, "num_steps": 128, "num_minibatches": 32}
    if total_steps is not None:
        shape["total_timesteps"] = int(total_steps)
    return shape
