"""Train a baseline on any single-agent world and evaluate it on the paper's suites: the pipeline
behind `specrl-jax train`, `specrl-jax run` and `specrl-jax reproduce`.

Seeds follow the paper's protocol: `num_seeds` independent trainings (side by side under
`vmap`), each evaluated with its own seed on `episodes` fresh layouts per spec; tables report the
mean and std over the seeds.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import time
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import jax
import numpy as np

from specrl_jax import cache, families, specs
from specrl_jax.baselines import hosts, runs
from specrl_jax.baselines.compile_log import in_background
from specrl_jax.baselines.params_io import load_params as read_params
from specrl_jax.baselines.params_io import load_params_into, save_params
from specrl_jax.baselines.ppo import PPOConfig, env_mesh, make_train
from specrl_jax.baselines.spec import get_method
from specrl_jax.envs import bank_cache
from specrl_jax.envs.registry import make
from specrl_jax.tasks.sources import ByContent

SUCCESS_LEVELS = (0.5, 0.8, 0.9, 0.95, 0.98)
#: a run directory's file holding the result of the method's phase before PPO (GCRL-LTL's
#: direction primitives, LTL2Action's pretrained encoder), read when the run resumes
PREPARED = "prepared.msgpack"


def family(env_id: str) -> str:
    """The world family of a single-agent env ID that methods train on ("letter", "zone", "arm")."""
    from specrl_jax.envs.registry import list_envs

    def trainable(e: str) -> bool:
        try:
            return families.family_of_id(e).trainable
        except ValueError:
            return False

    if env_id not in list_envs() or not trainable(env_id):
        raise ValueError(f"cannot train on env {env_id!r}; single-agent IDs: "
                         f"{', '.join(e for e in list_envs() if trainable(e))}")
    return families.family_of_id(env_id).name


def suites_for(env: str | Any) -> tuple[str, ...]:
    """The paper's evaluation suites of a world (or env ID): its family's suites over its own
    propositions (so the grippers-only arm takes its five, the grippers-and-arm arm its two)."""
    world = make(env)[0] if isinstance(env, str) else env
    return tuple(s for s in families.of(world).suites
                 if specs.suite_info(s).propositions == tuple(world.propositions))


def default_overrides(device_kind: str, total_steps: int | None = None,
                      world_family: str = "letter", method: str | None = None,
                      images: bool = False) -> dict[str, Any]:
    """The training shape of a world family on a device kind (`families.WorldFamily.rollout`):
    LetterWorld the reference's 16 x 128 on a CPU, 256 x 128 on an accelerator; ZoneEnv / Arm
    16 x 128 on a CPU, 512 x 128 (the arm 4,096 x 16) = 65,536 samples per update in minibatches
    of 2,048 on an accelerator (the reference's update size, 16 x 4096). The per-sample settings are unchanged
    (docs/fidelity.md), but for `method`'s own accelerator settings
    (`MethodSpec.accelerator_ppo`: GenZ-LTL's epochs capped at 10). A world that `images`
    (`observes_images`) learns its seeds in turn on an accelerator (`PPOConfig.learn_seeds_in_turn`:
    the same updates; its gradient steps fill the device alone, and each seed stops at its own KL)."""
    shape: dict[str, Any] = families.get(world_family).rollout_shape(device_kind)
    if method is not None and device_kind != "cpu":
        shape.update(get_method(method).accelerator_ppo)
    if images and device_kind != "cpu":
        shape["learn_seeds_in_turn"] = True
    if total_steps is not None:
        shape["total_timesteps"] = int(total_steps)
    return shape


def observes_images(env: str | Any, env_options: dict[str, Any] | None = None) -> bool:
    """Whether a world (or `make(env_id, **env_options)`) observes camera frames (the `Vision` IDs)."""
    world = make(env, **(env_options or {}))[0] if isinstance(env, str) else env
    return bool(getattr(getattr(world, "config", None), "vision", False))


#: method options naming a file (a world family's name instead picks the package's own)
FILE_OPTIONS = ("encoder",)


def check_settings(method: str, env_id: str, ppo_overrides: dict[str, Any],
                   method_options: dict[str, Any] | None = None) -> PPOConfig:
    """The cheap checks of a training's settings, made before any expensive step (map bank,
    method tables, compilation): a trainable env ID, options the method takes (files that
    exist), a valid PPO shape. Returns the PPOConfig."""
    spec = get_method(method)
    world_family = family(env_id)
    spec.check_options(method_options)
    for name in FILE_OPTIONS:
        value = (method_options or {}).get(name)
        if (isinstance(value, (str, os.PathLike)) and str(value) not in families.list_families()
                and not Path(value).is_file()):
            raise ValueError(f"method option {name}={str(value)!r}: no such file (a path, or a "
                             f"world family's name for the package's {name})")
    return spec.ppo_config(world_family, **ppo_overrides)


def with_method(method: str, world: Any, params: Any, map_bank: int | None, key: jax.Array,
                method_options: dict[str, Any] | None = None) -> tuple[Any, Any]:
    """(train params, method object) on a built world: the expensive part of `build`."""
    if map_bank and families.of(world).map_bank:
        # waits for the bank here: dispatched asynchronously, it would finish inside training
        params = bank_cache.with_map_bank(world, params, key, map_bank)
    method_obj = get_method(method).make_method(world, params, families.of(world).name,
                                                **(method_options or {}))
    return params, method_obj


def build(method: str, env_id: str, ppo_overrides: dict[str, Any], map_bank: int | None, key: jax.Array,
          env_options: dict[str, Any] | None = None, method_options: dict[str, Any] | None = None):
    """(world, train params, method object, PPOConfig) for `method` on `env_id` (built with
    `make(env_id, **env_options)`, the method with `make_method(..., **method_options)`);
    `map_bank` (families with a bank: LetterWorld, zones, the arm) draws training resets from a
    bank of that many exactly sampled layouts."""
    config = check_settings(method, env_id, ppo_overrides, method_options)
    if cache.programs_dir() is not None:  # the code this run traces, before a set-up edit
        cache.package_digest()
    world, params = make(env_id, **(env_options or {}))
    params, method_obj = with_method(method, world, params, map_bank, key, method_options)
    return world, params, method_obj, config


def program_key(method: str, run_config: dict[str, Any], world: Any, params: Any,
                method_obj: Any, mesh: Any, method_options: dict[str, Any] | None = None
                ) -> str | None:
    """The digest naming a training's traced programs on disk (`baselines.programs`): the run's
    settings (`runs.run_config`), the world's config and data (its params, the map bank among
    them), the arrays of the method object's fields (GCRL-LTL's primitives, a pretrained
    encoder), the files that options name, every file of the package, the versions, JAX's
    settings and the device. None with caching off, on several devices (`programs` keeps
    single-device programs) or on another than the default device (a stored program runs where
    its arguments are, not where the mesh says), where a program may run code outside the
    package (a method, its hooks or a world registered by the user), which no digest here sees,
    and where an option is an object rather than plain data (a network, a bank: its text need
    not name its content)."""
    spec = get_method(method)
    hooks = [h for h in (spec.make_method, spec.prepare_training, spec.finish_training) if h]
    default_device = jax.config.jax_default_device  # a device, a platform's name or None
    if default_device is None or isinstance(default_device, str):
        default_device = jax.local_devices(backend=default_device)[0]
    if (cache.programs_dir() is None or mesh.size > 1 or mesh.devices.flat[0] != default_device
            or not cache.in_package(type(world), *hooks)
            or not all(_plain(v) for v in (method_options or {}).values())):
        return None
    method_data = {}
    for field in dataclasses.fields(method_obj):
        value = getattr(method_obj, field.name)
        leaves = jax.tree.leaves(value)
        if leaves and all(isinstance(x, (jax.Array, np.ndarray)) for x in leaves):
            method_data[field.name] = ByContent(value).digest
    files = {name: hashlib.sha256(Path(value).read_bytes()).hexdigest()
             for name, value in (method_options or {}).items()
             if name in FILE_OPTIONS and isinstance(value, (str, os.PathLike))
             and Path(value).is_file()}
    return cache.digest({
        "run": run_config, "world": f"{type(world).__module__}.{type(world).__qualname__}",
        "world_config": repr(getattr(world, "config", None)), "params": ByContent(params).digest,
        "method_data": method_data, "files": files, "package": cache.package_digest(),
        "runtime": cache.runtime(), "device": mesh.devices.flat[0].id})


def _plain(value: Any) -> bool:
    """JSON-like data (numbers, strings, None, and lists, tuples and dicts of them)."""
    if isinstance(value, (list, tuple)):
        return all(_plain(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    return value is None or isinstance(value, (bool, int, float, str, os.PathLike))


def trained_steps(config: PPOConfig) -> int:
    """Env steps per seed a training of `config` takes: whole updates of `batch_size`."""
    return config.num_updates * config.batch_size


def lowers_in_threads(world: Any) -> bool:
    """Whether programs stepping `world` may be lowered and compiled beside other work in another
    thread: not with MuJoCo Warp, which builds its kernels as a program lowers."""
    return getattr(getattr(world, "physics", None), "backend", None) != "warp"


def warn_slow_camera(world: Any, platform: str) -> None:
    """A warning when a camera world renders large frames on a CPU (each step renders one per
    env: training takes hours)."""
    size = getattr(getattr(world, "config", None), "image_size", None)
    size = (size, size) if isinstance(size, int) else size
    if platform == "cpu" and observes_images(world) and size and size[0] * size[1] > 128 * 128:
        warnings.warn(f"training a camera world at {size[0]} x {size[1]} pixels on a CPU renders "
                      "a frame per env and step: expect hours; pass --env-option image_size=64 "
                      "(make(..., image_size=64)) for a CPU-sized camera", stacklevel=2)


def train(method: str, env_id: str, run_dir: str | Path, ppo_overrides: dict[str, Any], num_seeds: int = 1,
          seed: int = 0, map_bank: int | None = 65536, chunk_updates: int = 10,
          log: Callable[[str], None] = print, max_wall_s: float | None = None,
          restart: bool = False, devices: Sequence[Any] | None = None,
          env_options: dict[str, Any] | None = None, method_options: dict[str, Any] | None = None,
          on_compiled: Callable[[], None] | None = None, first_seed: int = 1
          ) -> tuple[Any, dict[str, Any]]:
    """Train `num_seeds` runs, seeds `first_seed` on (`runs.seed_keys`: trained in parts, a
    run's seeds are the ones it has trained at once); returns `(params with a leading seed
    axis, training summary)`.
    `env_options` are `make`'s overrides of the world (e.g. `{"image_size": 64}`),
    `method_options` the method's `make_method` options (e.g. `{"sampler": "curriculum"}`).
    `restart` discards a run directory's earlier run (else it is resumed if its settings match).
    `max_wall_s` stops training at the first checkpoint after that many seconds of this call,
    set-up included (resumable; a phase after training, `MethodSpec.finish_training`, waits for
    the run's last update: until then the policy's parameters are returned and no
    `params.msgpack` is written). `on_compiled()` runs once the training step has compiled,
    before it runs: host work that would slow the compilation down (another compilation).
    The env batch is sharded over `devices` (default: every device, of every process in a job
    of several; `num_envs` must divide by their count), parameters replicated; the result does
    not depend on the count beyond floating-point reduction order. In a job of several processes
    (`hosts.join`) every process calls it alike; process 0 writes the run directory and logs.
    The parameters are returned as numpy arrays."""
    key_bank, key_train = jax.random.split(jax.random.key(seed))
    log = hosts.writer_log(log)
    start = time.perf_counter()
    spec = get_method(method)
    # every setting is checked before the expensive steps (map bank, method tables, compilation)
    config = check_settings(method, env_id, ppo_overrides, method_options)
    mesh = env_mesh(list(devices) if devices is not None else None)
    make_train(config, None, mesh)  # checks the env batch against the devices
    world, params = make(env_id, **(env_options or {}))
    # Zone worlds: the backend "auto" chose, so that a run does not resume on another
    physics = getattr(getattr(world, "physics", None), "backend", None)
    extra_config = {"method": method, "env": env_id, "map_bank": map_bank, "seed": seed,
                    **({"env_options": dict(env_options)} if env_options else {}),
                    **({"physics": physics} if physics else {}),
                    **({"first_seed": first_seed} if first_seed != 1 else {}),
                    **({"method_options": dict(method_options)} if method_options else {})}
    runs.check_run_dir(run_dir, runs.run_config(config, num_seeds, extra_config), restart)
    warn_slow_camera(world, mesh.devices.flat[0].platform)
    if map_bank and families.of(world).map_bank:
        log(f"building a bank of {map_bank:,} exactly sampled layouts for training resets ...")
    params, method_obj = with_method(method, world, params, map_bank, key_bank, method_options)
    if spec.prepare_training is not None:  # a phase before PPO (GCRL-LTL's direction primitives)
        saved = Path(run_dir) / PREPARED if hosts.is_writer() else None
        if restart and saved is not None:
            saved.unlink(missing_ok=True)
        method_obj = spec.prepare_training(method_obj, key_train, config, log, saved)
    programs = program_key(method, runs.run_config(config, num_seeds, extra_config), world,
                           params, method_obj, mesh, method_options)
    setup = time.perf_counter() - start
    log(f"set up {env_id} in {setup:.1f}s; training {spec.title}, {num_seeds} x "
        f"{trained_steps(config):,} env steps ({config.num_updates:,} updates of "
        f"{config.num_envs} envs x {config.num_steps} steps); compiling takes seconds to minutes "
        "(seconds when the compilation cache holds it)")
    trainer = make_train(config, method_obj, mesh)
    # the set-up (map bank, GCRL-LTL's primitives) spends the wall-clock budget too
    budget = None if max_wall_s is None else max(0.0, max_wall_s - setup)
    start = time.perf_counter()
    runner = runs.train_in_run_dir(
        trainer, key_train, run_dir, chunk_updates, num_seeds, extra_config=extra_config,
        summarise=spec.summarise, log=log, max_wall_s=budget, restart=restart, first_chunk=1,
        program_key=programs, on_compiled=on_compiled,
        compile_step_early=lowers_in_threads(world), first_seed=first_seed,
    )
    wall = time.perf_counter() - start
    rows = runs.read_metrics(run_dir)
    params, updates = hosts.host_copy((runner.params, runner.update))
    complete = int(updates[0]) >= config.num_updates
    # the phase after training (GCRL-LTL's values) waits for the whole policy
    policy_only = spec.finish_training is not None and not complete
    if policy_only:
        log("training stopped early: the phase after training runs once the run resumes to its "
            "last update")
    elif spec.finish_training is not None:
        params = spec.finish_training(method_obj, params, key_train, config, log, programs,
                                      first_seed)
    summary = {
        "method": method, "env": env_id, "num_seeds": num_seeds,
        "seeds": list(range(first_seed, first_seed + num_seeds)), "ppo": dataclasses.asdict(config),
        "env_steps_per_seed": rows[-1]["env_steps"] if rows else 0,
        "complete": complete,
        "devices": int(mesh.size),  # the env batch was sharded over this many devices
        "processes": jax.process_count(),  # ... of this many processes
        "physics": physics,  # Zone worlds
        "setup_s": setup,  # env and map bank, before training
        "wall_s_this_call": wall,  # this call of train, resumed or not
        # every call's steps over every call's training time (the rows' clock spans resumes)
        "env_steps_per_s": rows[-1]["env_steps"] * num_seeds / rows[-1]["wall_s"] if rows else 0.0,
        "final_success_rate": rows[-1].get("success_rate") if rows else None,
        "time_to_success": time_to_levels(rows),
    }
    if hosts.is_writer():
        if policy_only:  # the policy alone does not load as the method's parameters
            (Path(run_dir) / "params.msgpack").unlink(missing_ok=True)
        else:
            save_params(Path(run_dir) / "params.msgpack", params)
        (Path(run_dir) / "train_summary.json").write_text(json.dumps(summary, indent=1))
    hosts.barrier("parameters written")
    return params, summary


def time_to_levels(rows: Sequence[dict[str, Any]], levels: Sequence[float] = SUCCESS_LEVELS) -> dict[str, Any]:
    """First (env steps, wall s) at which the seed-mean training success rate reaches each level."""
    found = {}
    for level in levels:
        hit = next((r for r in rows if r.get("success_rate", 0.0) >= level), None)
        found[str(level)] = None if hit is None else {"env_steps": hit["env_steps"], "wall_s": hit["wall_s"]}
    return found


def make_method(method: str, world: Any, params: Any, world_family: str | None = None,
                options: dict[str, Any] | None = None) -> Any:
    """`method`'s trainer object on `world` (its family unless `world_family`), options checked."""
    spec = get_method(method)
    spec.check_options(options)
    return spec.make_method(world, params, families.name_of(world, world_family), **(options or {}))


def make_policy(method: str, world: Any, method_obj: Any, deterministic: bool | None = None,
                world_family: str | None = None, **options: Any):
    """The method's test-time agent; `deterministic` None = the reference's setting
    (`MethodSpec.deterministic`: GenZ-LTL mode actions; DeepLTL and GCRL-LTL sampled actions on
    LetterWorld, mode actions elsewhere; DeepLTL sampled actions on every infinite spec,
    `MethodSpec.deterministic_infinite`); an explicit `deterministic` holds for every spec."""
    spec = get_method(method)
    family = families.name_of(world, world_family)
    if spec.deterministic_infinite is not None:  # an explicit mode holds for every spec
        options.setdefault("deterministic_infinite", spec.deterministic_infinite(family)
                           if deterministic is None else deterministic)
    if deterministic is None:
        deterministic = spec.deterministic(family)
    if spec.policy_options is not None:
        options = {**spec.policy_options(method_obj), **options}
    return spec.make_policy(method_obj.network, world.alphabet, world.obs_kinds,
                            deterministic=deterministic, **options)


def evaluate(method: str, env_id: str, params: Any, suites: Sequence[str], episodes: int,
             log: Callable[[str], None] = print, deterministic: bool | None = None,
             label: str | None = None, horizon: int | None = None,
             env_options: dict[str, Any] | None = None, devices: Sequence[Any] | None = None,
             method_options: dict[str, Any] | None = None, seeds: Sequence[int] | None = None,
             **policy_options: Any) -> list:
    """Evaluate every trained seed (leading axis of `params`, evaluation seed i + 1 for entry i,
    or `seeds[i]`) on `suites`
    (`eval.suites.evaluate_suites`: infinite suites over 10 finite horizons unless `horizon`;
    episodes sharded over `devices`, default every local device).
    Returns `SuiteResult`s with one row per trained seed."""
    return prepare_evaluation(method, env_id, params, suites, episodes, log, deterministic, label,
                              horizon, env_options, devices, method_options, seeds,
                              **policy_options)(params)


def prepare_evaluation(method: str, env_id: str, params: Any, suites: Sequence[str],
                       episodes: int, log: Callable[[str], None] = print,
                       deterministic: bool | None = None, label: str | None = None,
                       horizon: int | None = None, env_options: dict[str, Any] | None = None,
                       devices: Sequence[Any] | None = None,
                       method_options: dict[str, Any] | None = None,
                       seeds: Sequence[int] | None = None,
                       **policy_options: Any) -> Callable[[Any], list]:
    """`evaluate`'s program, compiled now for parameters shaped as `params` (arrays, or
    `param_shapes`' structs: compiled while the parameters train); returns the function that
    evaluates parameters of those shapes (`eval.suites.compile_suites`)."""
    from specrl_jax.eval.suites import compile_suites

    spec = get_method(method)
    if spec.usable_suites is not None:  # RAD: co-safe suites only
        suites = spec.usable_suites(suites, log)
    world, env_params = make(env_id, **(env_options or {}))
    method_obj = make_method(method, world, env_params, None, method_options)
    if spec.policy_takes_suites:
        policy_options.setdefault("suites", tuple(suites))  # LTL2Action progresses their formulas
    policy = make_policy(method, world, method_obj, deterministic, None, **policy_options)
    num_seeds = jax.tree.leaves(params)[0].shape[0]
    return compile_suites(
        policy, env_id, world, env_params, suites, episodes,
        seeds=range(1, num_seeds + 1) if seeds is None else seeds,
        policy_params=params, params_per_seed=True, horizon=horizon,
        label=label or spec.title, log=log, devices=devices,
    )


def prepare_evaluation_in_background(method: str, env_id: str, num_seeds: int,
                                     suites: Sequence[str], episodes: int,
                                     log: Callable[[str], None] = print,
                                     env_options: dict[str, Any] | None = None,
                                     method_options: dict[str, Any] | None = None,
                                     seeds: Sequence[int] | None = None) -> Future:
    """`prepare_evaluation` for the parameters `num_seeds` seeds of `method` will have (seeds
    1 .. num_seeds, or `seeds`), compiling in another thread (e.g. while they train); the
    future holds `evaluate(params)`."""
    shapes = param_shapes(method, env_id, len(seeds) if seeds else num_seeds, env_options,
                          method_options)
    return in_background(functools.partial(
        prepare_evaluation, method, env_id, shapes, suites, episodes, log=log,
        env_options=env_options, method_options=method_options, seeds=seeds))


def param_shapes(method: str, env_id: str, num_seeds: int | None = None,
                 env_options: dict[str, Any] | None = None,
                 method_options: dict[str, Any] | None = None) -> Any:
    """`jax.ShapeDtypeStruct`s of a method's parameters on a world (with a leading axis of
    `num_seeds` if given), found without running the env or the network."""
    world, env_params = make(env_id, **(env_options or {}))
    spec = get_method(method)
    method_obj = make_method(method, world, env_params, None, method_options)
    obs, _ = jax.eval_shape(method_obj.env.reset, jax.random.key(0), method_obj.init_task_params())
    one_obs = jax.tree.map(lambda x: jax.ShapeDtypeStruct((1, *x.shape), x.dtype), obs)
    one = jax.eval_shape(method_obj.network.init, jax.random.key(0), one_obs)
    if spec.param_shapes is not None:  # parameters beyond the PPO network's
        one = spec.param_shapes(method_obj, one)
    if num_seeds is None:
        return one
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct((num_seeds, *x.shape), x.dtype), one)


def load_params(method: str, env_id: str, path: str | Path, num_seeds: int,
                env_options: dict[str, Any] | None = None,
                method_options: dict[str, Any] | None = None) -> Any:
    """Read `params.msgpack` written by `train` (leading seed axis), or one seed's parameters
    without that axis (the results store's `params_seed1.msgpack`), returned with it."""
    spec = get_method(method)
    # shapes only: running the env's reset and the network's init eagerly takes seconds on a CPU
    one = param_shapes(method, env_id, None, env_options, method_options)
    stored = read_params(path, what=f"{spec.title} parameters")
    leaf = jax.tree.leaves(stored)[0]
    if num_seeds == 1 and np.ndim(leaf) == len(jax.tree.leaves(one)[0].shape):
        single = jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), one)
        return jax.tree.map(lambda x: x[None], load_params_into(single, stored))
    template = jax.tree.map(lambda x: np.zeros((num_seeds, *x.shape), x.dtype), one)
    return load_params_into(template, stored)
