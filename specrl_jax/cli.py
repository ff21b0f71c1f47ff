"""The `specrl-jax` command line: `envs`, `specs`, `eval`, `bench`, `train`, `run`, ... (one
function per subcommand).

A subcommand is one function taking the parsed arguments, registered with its options by
`@command(name, help, arg(...), ...)`; `main` builds the parser from the registry.

    specrl-jax envs
    specrl-jax specs [--prefix letter/]
    specrl-jax eval --env LetterLTL0-v0 --policy oracle --suite letter/finite/ind \\
        --seeds 5 --episodes 100 --out results/
    specrl-jax eval --env LetterLTL0-v0 --policy runs/genz --suite letter/finite/ood --seed 2
    specrl-jax bench --policy my_package.agents:make_agent --worlds letter,zone --out bench/
    specrl-jax train --method genz --env PointLTL0-v0 --seeds 5
    specrl-jax run
"""

from __future__ import annotations

import argparse
import ast
import atexit
import gc
import re
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from pathlib import Path
from typing import Any

Command = Callable[[argparse.Namespace], int]
COMMANDS: dict[str, tuple[str, tuple[tuple[tuple, dict], ...], Command]] = {}
POLICIES = ("random", "oracle")


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    return _int_at_least(text, 1)


def nonnegative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    return _int_at_least(text, 0)


SEED_RANGE_HELP = ("train and evaluate only these seeds of each cell, e.g. 1-2 now and 3-5 later: "
                   "a cell too long for one machine's time is completed in parts, each kept "
                   "beside the seeds the store holds; the seeds get the keys they have in one "
                   "training of them all")


def seed_range(text: str) -> list[int]:
    """argparse type: FIRST-LAST (or one seed) -> the seed numbers FIRST..LAST, from 1."""
    match = re.fullmatch(r"(\d+)(?:-(\d+))?", text.strip())
    seeds = list(range(int(match[1]), int(match[2] or match[1]) + 1)) if match else []
    if not seeds or seeds[0] < 1:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a seed range: give FIRST-LAST with 1 <= FIRST <= LAST, e.g. 3-5")
    return seeds


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number above 0, got {text!r}")
    return value


#: the shell's spellings of booleans and None, read as Python's
_WORDS = {"true": True, "false": False, "none": None}


def env_option(text: str) -> tuple[str, Any]:
    """argparse type: `KEY=VALUE`, the value read as a Python literal (int, float, bool, tuple;
    true / false / none in any case too) or else kept as a string."""
    key, sep, value = text.partition("=")
    if not sep or not key.isidentifier():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE (e.g. image_size=64), got {text!r}")
    if value.lower() in _WORDS:
        return key, _WORDS[value.lower()]
    try:
        return key, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return key, value


def _int_at_least(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {value}")
    if value >= 2**31:
        raise argparse.ArgumentTypeError(f"expected an integer below 2**31, got {value}")
    return value


def arg(*flags: str, **options: Any) -> tuple[tuple, dict]:
    """One `add_argument` call, as data."""
    return flags, options


def command(name: str, help: str, *arguments: tuple[tuple, dict]) -> Callable[[Command], Command]:
    """Register `fn(args) -> exit code` as subcommand `name` with its arguments."""

    def register(fn: Command) -> Command:
        if name in COMMANDS:
            raise ValueError(f"subcommand {name!r} is already registered")
        COMMANDS[name] = (help, arguments, fn)
        return fn

    return register


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="specrl-jax", description=__doc__.splitlines()[0] + " " + __doc__.splitlines()[1])
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (help_text, arguments, fn) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        for flags, options in arguments:
            p.add_argument(*flags, **options)
        p.set_defaults(run=fn)
    return parser


def enable_compilation_cache() -> None:
    """JAX's persistent compilation cache under `$SPECRL_JAX_CACHE_DIR/jax` (default
    ~/.cache/specrl_jax/jax, `off` to disable), unless one is configured already, storing every
    compiled program, so that a second identical run compiles nothing (`specrl_jax.cache`)."""
    from specrl_jax import cache

    cache.enable_jax_cache(cache.CLI_MIN_COMPILE_SECONDS)


#: `train` and `reproduce` as one job over several processes (hosts)
PROCESS_ARGS = (
    arg("--coordinator", default=None, metavar="HOST:PORT",
        help="several hosts: run the same command on each, with process 0's HOST and a free PORT; "
             "JAX_COORDINATOR_ADDRESS when absent (under Slurm or Open MPI JAX reads the rest: "
             "leave the three flags out). The env batch is sharded over every process's devices; "
             "process 0 alone writes --out (or --store), and every process resumes from its "
             "checkpoint: put it on a filesystem that every host shares"),
    arg("--num-processes", type=positive_int, default=None, metavar="N",
        help="several hosts: processes in the job (with --coordinator and --process-id)"),
    arg("--process-id", type=nonnegative_int, default=None, metavar="I",
        help="several hosts: this process's index, 0..N-1; process 0 writes and prints"),
)


def join_processes(args: argparse.Namespace) -> None:
    """Join the job of several processes named by `--coordinator`, `--num-processes`,
    `--process-id` or the environment (`baselines.hosts`), before any JAX computation."""
    from specrl_jax.baselines import hosts

    hosts.join(hosts.process_group(args.coordinator, args.num_processes, args.process_id))


def load_world_modules(env_id: str, own_process: bool = False) -> None:
    """Import MuJoCo MJX for an ID of a MuJoCo world, unless loaded, saying so on stderr:
    importing it (with MuJoCo Warp where installed) takes 5-15 s on a CPU. In a process of its
    own (`own_process`: the `specrl-jax` script, not a caller's `main([...])`) the garbage
    collector pauses meanwhile and then freezes what is alive (`gc.freeze`): Python's full
    collections, run whenever the heap grows by a quarter, would walk the ~600,000 objects of
    MJX and JAX again and again (about a second on a CPU)."""
    if env_id.startswith("Letter") or "mujoco.mjx" in sys.modules:
        return
    print("loading the world modules (MuJoCo MJX: seconds) ...", file=sys.stderr, flush=True)
    if own_process:
        gc.disable()
    try:
        from specrl_jax.envs.zone import mjx_import  # noqa: F401
    finally:
        if own_process:
            gc.freeze()
            gc.enable()


def main(argv: Sequence[str] | None = None) -> int:
    """The command line `argv` (None: the process's own, `sys.argv[1:]`); returns the exit
    status."""
    args = build_parser().parse_args(argv)
    args.own_process = argv is None
    if args.own_process:
        # The exit skips Python's final garbage collections (a second or two after importing
        # MJX): the process ends, and the operating system takes its memory back.
        atexit.register(gc.freeze)
    try:
        return args.run(args)
    except KeyboardInterrupt as err:
        update = getattr(err, "update", None)  # `runs.TrainingInterrupted`: a checkpoint there
        where = "" if update is None else f" at update {update}; run the same command to resume"
        print(f"specrl-jax {args.command}: interrupted{where}", file=sys.stderr)
        return 130
    except (ValueError, TypeError) as err:
        print(f"specrl-jax {args.command}: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"specrl-jax {args.command}: error: {err.strerror or err}: {err.filename or ''}",
              file=sys.stderr)
        return 2


@command("envs", "List the registered env IDs.")
def list_envs_command(args: argparse.Namespace) -> int:
    from specrl_jax.envs.registry import describe, list_envs

    for env_id in list_envs():
        print(f"{env_id:32s} {describe(env_id)}")
    return 0


@command("specs", "List the named specification suites.",
         arg("--prefix", default="", help="only suites whose name starts with this"),
         arg("--formulas", action="store_true", help="also print every formula"))
def list_specs_command(args: argparse.Namespace) -> int:
    from specrl_jax import specs

    for name in specs.list_suites():
        if name.startswith(args.prefix):
            info = specs.suite_info(name)
            print(f"{name:48s} {info.horizon:8s} {len(info.formulas):3d} formulas")
            if args.formulas:
                for formula in info.formulas:
                    print(f"    {formula}")
    return 0


def make_policy(name: str, env: Any) -> Any:
    """A policy by name: `random` (any env) or `oracle` (the LetterWorld planner)."""
    from specrl_jax.eval.planner import oracle_policy
    from specrl_jax.tasks.policy import random_policy

    if name == "random":
        return random_policy(env)
    if name == "oracle":
        return oracle_policy(env)
    raise ValueError(f"unknown policy {name!r}; known policies: {', '.join(POLICIES)}")


@command(
    "eval", "Evaluate a policy on specification suites and write JSON, Markdown and plots.",
    arg("--env", required=True, help="env ID, e.g. LetterLTL0-v0"),
    arg("--policy", required=True,
        help=f"one of: {', '.join(POLICIES)}; a run directory of `specrl-jax train` (method, "
             "world and settings from its config.json); a results-store cell such as "
             "LetterLTL0-v0/genz; or package.module:factory, a function (world) -> policy or "
             "Agent (README: 'Scoring your own policy')"),
    arg("--suite", required=True, action="append", help="suite name (repeat for several)"),
    arg("--seeds", type=positive_int, default=None,
        help="number of seeds; seeds are 1..N (default 5; a run directory: all of its seeds)"),
    arg("--seed", default="all",
        help="a run directory: evaluate only this one of its seeds (1..N), or all (default)"),
    arg("--episodes", type=positive_int, default=100, help="episodes per seed and spec (default 100)"),
    arg("--horizon", type=positive_int, default=None,
        help="episode horizon of every suite (default: the env's for finite suites, 10x for infinite)"),
    arg("--out", default="results", help="output directory (default results/)"),
    arg("--trajectories", type=nonnegative_int, default=4, help="episodes drawn on the map (LetterWorld)"),
    arg("--no-progress", action="store_true", help="no progress bar"),
)
def eval_command(args: argparse.Namespace) -> int:
    enable_compilation_cache()
    from specrl_jax.benchmark import agent as agents
    from specrl_jax.envs.registry import make
    from specrl_jax.eval import report

    env, params = make(args.env)
    seed = None if args.seed == "all" else positive_int(args.seed)
    loaded = agents.load(args.policy, args.env, seed=seed, world=env)
    if isinstance(loaded, agents.TrainedRun):
        loaded = agents.with_seed_count(loaded, args.seeds)
        seeds = list(loaded.seeds)
    elif seed is not None:
        raise ValueError(f"--seed picks a seed of a trained run; {args.policy!r} is not one "
                         "(give --seeds N)")
    else:
        seeds = list(range(1, (args.seeds or 5) + 1))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log = (lambda line: None) if args.no_progress else (lambda line: print(line, file=sys.stderr))
    results = agents.evaluate(loaded, args.env, args.suite, args.episodes, seeds, args.horizon, log)

    config = {key: value for key, value in vars(args).items() if key != "run"}
    config["seed_list"] = seeds
    if isinstance(loaded, agents.TrainedRun):
        config.update(method=loaded.method, trained=loaded.source)
    written = [report.write_json(out / "eval.json", results, config)]
    table = report.markdown_tables(results)
    (out / "eval.md").write_text(table)
    written.append(out / "eval.md")
    complexity = report.plot_complexity(results, out / "complexity.png")
    if complexity:
        written.append(complexity)
    if (args.trajectories > 0 and _is_letter_world(env) and isinstance(loaded, agents.Agent)
            and loaded.params is None):
        written.append(_draw_trajectories(loaded.policy, env, params, args,
                                          out / "trajectories.png"))
    print(table)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def _is_letter_world(env: Any) -> bool:
    return hasattr(getattr(env, "config", None), "grid_size") and hasattr(env, "layout")


def _draw_trajectories(policy: Any, env: Any, params: Any, args: argparse.Namespace,
                       path: Path) -> Path:
    """A few episodes of the first suite's first specs, drawn on their maps."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from specrl_jax import automata, specs
    from specrl_jax.eval import report
    from specrl_jax.eval.evaluate import record_episodes
    from specrl_jax.tasks import TaskEnv

    formulas = specs.suite(args.suite[0])
    count = args.trajectories
    index = np.arange(count) % len(formulas)
    compiled = automata.compile_suite(formulas, env.propositions, env.alphabet)
    keys = jax.random.split(jax.random.key(1), count)
    states, alive = jax.device_get(record_episodes(
        policy, TaskEnv(env, compiled), params, keys, jnp.asarray(index)))
    letters, paths, titles = [], [], []
    layouts = jax.vmap(jax.vmap(env.layout))(states.env_state)  # leaves [B, T + 1, ...]
    for i in range(count):
        steps = int(alive[i].sum())
        letters.append(np.asarray(layouts["letters"][i, 0]))
        paths.append(np.asarray(layouts["agent"][i, :steps]))
        outcome = ("success" if states.success[i, -1] else
                   "violation" if states.violation[i, -1] else "timeout")
        titles.append(f"{formulas[index[i]]}\n{outcome} after {steps - 1} steps")
    return report.plot_trajectories(np.stack(letters), paths, titles, env.propositions, path)


@command(
    "train",
    "Train a baseline (GenZ-LTL, DeepLTL, LTL2Action, GCRL-LTL or RAD-Embeddings) with the "
    "shared PPO on any "
    "single-agent world; writes a run directory.",
    arg("--method", required=True, choices=("genz", "deepltl", "ltl2action", "gcrl", "rad")),
    arg("--env", default="LetterLTL0-v0", help="any single-agent env ID (`specrl-jax envs`)"),
    arg("--seeds", type=positive_int, default=1, help="independent runs trained side by side"),
    arg("--seed", type=nonnegative_int, default=0, help="base seed of the runs (default 0)"),
    arg("--total-steps", type=positive_int, default=None,
        help="env interactions per run (default 15M on an accelerator, 200k on a CPU)"),
    arg("--num-envs", type=positive_int, default=None, help="envs stepped side by side per run"),
    arg("--num-steps", type=positive_int, default=None, help="rollout steps per env and update"),
    arg("--restart", action="store_true", help="discard a run already in --out instead of resuming it"),
    arg("--map-bank", type=nonnegative_int, default=None,
        help="exactly sampled layouts in the bank training resets draw from (default 65,536 "
             "on an accelerator; on a CPU LetterWorld 4,096, zones and the arm 512: set-up in "
             "seconds to a minute; cached on disk; 0: exact resets)"),
    arg("--out", default=None, help="run directory (default runs/<method>); resumes if present"),
    arg("--eval-episodes", type=nonnegative_int, default=0, help="then evaluate on the world's paper suites"),
    arg("--env-option", type=env_option, action="append", default=[], metavar="KEY=VALUE",
        help="an override of the world passed to make(), e.g. image_size=64 (repeatable)"),
    arg("--method-option", type=env_option, action="append", default=[], metavar="KEY=VALUE",
        help="an option of the method (repeatable), e.g. for ltl2action sampler=curriculum, "
             "encoder=ENCODER.msgpack (a pretrained formula encoder), freeze_encoder=True, "
             "pretrain_steps=10000000; for rad sampler=rad; for deepltl stay_steps=300 (longer "
             "reach-stay tasks), twins_apart=True (no avoid set holds its reach's same-object "
             "proposition, the grippers-and-arm Arm's arm_c / grippers_c); for every method "
             "image_dtype=bfloat16 (the image CNN's convolutions in bfloat16); a wrong key lists "
             "the accepted ones"),
    *PROCESS_ARGS,
)
def train_command(args: argparse.Namespace) -> int:
    join_processes(args)
    enable_compilation_cache()
    import jax

    from specrl_jax import families
    from specrl_jax.benchmark import experiment
    from specrl_jax.eval import report

    platform = jax.devices()[0].platform
    load_world_modules(args.env, args.own_process)
    world_family = experiment.family(args.env)
    total = args.total_steps or families.default_total_steps(platform)
    images = experiment.observes_images(args.env, dict(args.env_option))
    overrides = experiment.default_overrides(platform, total, world_family, args.method, images)
    overrides.update({k: v for k, v in (("num_envs", args.num_envs), ("num_steps", args.num_steps))
                      if v is not None})
    out = Path(args.out or f"runs/{args.method}")
    env_options = dict(args.env_option)
    method_options = dict(args.method_option)
    map_bank = (families.get(world_family).map_bank_size(platform) if args.map_bank is None
                else args.map_bank)
    params, summary = experiment.train(args.method, args.env, out, overrides, args.seeds, args.seed,
                                       map_bank=map_bank or None, restart=args.restart,
                                       env_options=env_options, method_options=method_options)
    if jax.process_index() != 0:  # process 0 of several reports and evaluates
        return 0
    print(f"trained {args.seeds} x {summary['env_steps_per_seed']:,} steps, "
          f"{summary['env_steps_per_s']:,.0f} env-steps/s; run directory {out}")
    if args.eval_episodes > 0:
        results = experiment.evaluate(args.method, args.env, params,
                                      experiment.suites_for(args.env), args.eval_episodes,
                                      env_options=env_options, method_options=method_options)
        report.write_json(out / "eval.json", results, {"train": summary})
        print(report.markdown_tables(results))
    print(f"wrote {out}/: config.json, metrics.jsonl, checkpoint.msgpack, params.msgpack, "
          f"train_summary.json, curve.png" + (", eval.json" if args.eval_episodes > 0 else ""))
    return 0


@command(
    "run",
    "The main demo: train GenZ-LTL on LetterWorld, evaluate on the finite suites (IND, OOD), "
    "print the paper-format table (a few minutes on a CPU; the paper's 15M steps on a GPU).",
    arg("--total-steps", type=positive_int, default=None,
        help="default 15M on an accelerator, 200k on a CPU"),
    arg("--seeds", type=positive_int, default=None, help="default 5 on an accelerator, 1 on a CPU"),
    arg("--episodes", type=positive_int, default=None,
        help="per spec and seed; default 100 (GPU) / 20 (CPU)"),
    arg("--out", default="runs/run",
        help="run directory (default runs/run); a run with the same settings there is resumed"),
    arg("--restart", action="store_true", help="discard a run already in --out instead of resuming it"),
    arg("--params", default=None,
        help="evaluate saved GenZ-LTL parameters (params.msgpack of a run) instead of training"),
)
def run_command(args: argparse.Namespace) -> int:
    enable_compilation_cache()
    import jax

    from specrl_jax import families
    from specrl_jax.benchmark import experiment
    from specrl_jax.eval import report

    gpu = jax.devices()[0].platform != "cpu"
    total = args.total_steps or families.default_total_steps(jax.devices()[0].platform)
    seeds = args.seeds or (5 if gpu else 1)
    episodes = args.episodes or (100 if gpu else 20)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    suites = ("letter/finite/ind", "letter/finite/ood")
    evaluation: list[Future] = []
    if args.params:  # a file of `--seeds` runs (default 1), e.g. the committed GPU-trained agent
        params = experiment.load_params("genz", "LetterLTL0-v0", args.params, args.seeds or 1)
        summary = {"loaded_from": args.params}
    else:
        def compile_evaluator() -> None:  # on the host while the device trains
            evaluation.append(experiment.prepare_evaluation_in_background(
                "genz", "LetterLTL0-v0", seeds, suites, episodes))

        overrides = experiment.default_overrides("gpu" if gpu else "cpu", total, "letter", "genz")
        if not gpu:  # a short budget: fewer epochs per update keeps it to minutes on two cores
            overrides.update(num_envs=32, num_steps=64, update_epochs=10)
        config = experiment.check_settings("genz", "LetterLTL0-v0", overrides)
        steps = experiment.trained_steps(config)
        rounded = (f" ({total:,} rounded down to whole updates of {config.batch_size:,})"
                   if steps != total else "")
        print(f"training GenZ-LTL on LetterLTL0-v0: {seeds} x {steps:,} steps{rounded} into {out}",
              flush=True)
        map_bank = families.LETTER.map_bank_size("gpu" if gpu else "cpu")
        params, summary = experiment.train("genz", "LetterLTL0-v0", out, overrides, seeds,
                                           map_bank=map_bank, restart=args.restart,
                                           on_compiled=compile_evaluator if gpu else None)
        print(f"trained GenZ-LTL: {seeds} x {summary['env_steps_per_seed']:,} steps at "
              f"{summary['env_steps_per_s']:,.0f} env-steps/s")
    print(f"evaluating on {', '.join(suites)}: {episodes} episodes per spec and seed", flush=True)
    if evaluation:
        results = evaluation[0].result()(params)  # placed as its program takes them
    else:
        results = experiment.evaluate("genz", "LetterLTL0-v0", params, suites, episodes)
    path = report.write_json(out / "results.json", results, {"train": summary, "episodes": episodes})
    print(report.markdown_tables(results))
    print(f"wrote {path}" + ("" if args.params else f"; the run directory is {out}/"))
    return 0


@command(
    "pretrain",
    "Pretrain a method's formula encoder on the symbol task (RAD-Embeddings' pretraining, "
    "LTL2Action's LTLBootcamp) and save it with a JSON beside it saying how it was made; by "
    "default over the package's shipped encoder of that family.",
    arg("--method", required=True, help="a method with a pretrained encoder: rad, ltl2action"),
    arg("--family", default="letter", help="world family whose alphabet it reads (default letter)"),
    arg("--env", default=None,
        help="a world ID whose alphabet it reads instead of the family's reference world (e.g. "
             "PointLTL1-v0, whose moving zones can overlap: RAD's zone_overlap encoder)"),
    arg("--steps", type=positive_int, default=None,
        help="symbol-task env steps (default 10M on an accelerator, 65,536 on a CPU)"),
    arg("--num-envs", type=positive_int, default=None, help="default: the original's 16"),
    arg("--num-steps", type=positive_int, default=None, help="default: the original's 512"),
    arg("--minibatches", type=positive_int, default=None, help="default: the original's 8"),
    arg("--seed", type=nonnegative_int, default=0, help="default 0"),
    arg("--out", default=None, help="encoder file (.msgpack); default: the shipped encoder's path"),
)
def pretrain_command(args: argparse.Namespace) -> int:
    import time

    from specrl_jax import families
    from specrl_jax.baselines.params_io import save_params
    from specrl_jax.baselines.spec import get_method, list_methods

    spec = get_method(args.method)
    if spec.pretrain is None:
        with_one = [m for m in list_methods() if get_method(m).pretrain is not None]
        raise ValueError(f"{spec.title} has no pretrained encoder; methods with one: "
                         f"{', '.join(with_one)}")
    from specrl_jax.envs.registry import make

    record = None if args.env else families.get(args.family)
    if record is not None and not record.reference_env:
        raise ValueError(f"world family {args.family!r} names no reference world to pretrain on")
    env_id = args.env or record.reference_env
    world, _ = make(env_id)
    record = families.of(world)
    encoder = families.encoder_name(record.name, world.alphabet, spec.encoder_per_symbol)
    out = Path(args.out) if args.out else spec.shipped_encoder(encoder)
    enable_compilation_cache()
    import flax
    import jax

    device = jax.devices()[0]
    steps = args.steps or (10_000_000 if device.platform != "cpu" else 65_536)
    shape = {name: value for name, value in (("num_envs", args.num_envs),
                                             ("num_steps", args.num_steps),
                                             ("num_minibatches", args.minibatches))
             if value is not None}
    lines: list[str] = []

    def log(line: str) -> None:
        lines.append(line)
        print(line, flush=True)

    print(f"pretraining {spec.title}'s encoder on {env_id}'s alphabet for "
          f"{steps:,} symbol-task steps (the first chunk includes compilation)", flush=True)
    start = time.perf_counter()
    params = spec.pretrain(world, record.name, jax.random.key(args.seed), steps, log, **shape)
    wall = time.perf_counter() - start
    meta = {"method": spec.name, "family": record.name, "alphabet_env": env_id,
            "steps": steps, "ppo_shape": shape, "seed": args.seed, "wall_s_with_compile": wall,
            "last_progress": lines[-1] if lines else "", "device": str(device.device_kind),
            "jax": jax.__version__, "flax": flax.__version__, "date": time.strftime("%Y-%m-%d"),
            "command": "specrl-jax pretrain " + " ".join(sys.argv[2:])}
    save_params(out, params, meta)
    print(f"saved {out} (and {out.with_suffix('.json').name}) after {wall:.1f}s")
    return 0


@command(
    "reproduce",
    "Reproduce the paper's experiment grid into the results store: train and evaluate each "
    "selected cell, skipping done cells and resuming partial ones (one cell per GPU).",
    arg("--cells", default=None,
        help="fnmatch pattern(s) of cell names, comma-separated (default: every cell), e.g. "
             "'LetterLTL0-v0/genz' or 'Panda*/*'"),
    arg("--list", action="store_true", help="show the grid: each cell's state and estimated GPU time"),
    arg("--store", default=None, help="results store directory (default: the package's)"),
    arg("--gpus", type=positive_int, default=None,
        help="cells run side by side (default: the visible GPUs; 1: one after the other)"),
    arg("--cells-per-gpu", type=positive_int, default=1, metavar="K",
        help="run K cells side by side on each GPU, each process with 1/K of the memory one "
             "would take (default 1): for cells whose steps leave the GPU idle between kernel "
             "launches"),
    arg("--seeds", type=positive_int, default=None,
        help="seeds per cell (default 5): fewer for smoke runs"),
    arg("--seed-range", type=seed_range, default=None, metavar="FIRST-LAST", help=SEED_RANGE_HELP),
    arg("--total-steps", type=positive_int, default=None, help="smoke runs: env steps per seed"),
    arg("--episodes", type=positive_int, default=None, help="smoke runs: episodes per spec and seed"),
    arg("--num-envs", type=positive_int, default=None, help="smoke runs: envs per seed"),
    arg("--rerun", action="store_true",
        help="discard the selected cells' stored results and run them end to end again"),
    arg("--max-minutes", type=positive_float, default=None,
        help="stop cleanly after this many minutes: training checkpoints at its next chunk (10 "
             "updates), no further cell starts, nor an evaluation estimated to end past them; "
             "the same command resumes. A training that completes in time still runs its "
             "method's phase after training (GCRL-LTL's value functions, 1-2 minutes on a "
             "GPU): leave room for it"),
    *PROCESS_ARGS,
)
def reproduce_command(args: argparse.Namespace) -> int:
    from specrl_jax.benchmark import reproduce

    if not args.list:
        join_processes(args)
    return reproduce.run_from_args(args)


@command(
    "report",
    "Render the results page (docs/results.md) and its figures from the results store, the "
    "paper's published numbers and the measurements file.",
    arg("--store", default=None, help="results store directory (default: the package's)"),
    arg("--out", default="docs/results.md", help="the page to write (default docs/results.md)"),
    arg("--figures", default=None, help="figure directory (default: figures/ beside --out)"),
)
def report_command(args: argparse.Namespace) -> int:
    from specrl_jax.benchmark import report

    written = report.render(store=args.store, out=args.out, figures=args.figures)
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


@command(
    "bench",
    "Score a policy on every paper suite of the selected worlds (5 seeds x 100 episodes) and "
    "write a report directory: JSON and CSV of every metric, the paper's tables with the five "
    "baselines beside it, a summary line per world, a plot, and the package's and suites' versions.",
    arg("--policy", required=True,
        help="a run directory of `specrl-jax train`, a results-store cell, random, oracle, or "
             "package.module:factory (README: 'Scoring your own policy')"),
    arg("--worlds", default=None,
        help="comma-separated: letter, zone, arm, multi_agent, or env IDs (default: a run's own "
             "world; else the worlds the policy declares, else all)"),
    arg("--suite", action="append", default=None, help="only this suite (repeatable)"),
    arg("--seeds", type=positive_int, default=5, help="seeds 1..N (default 5)"),
    arg("--episodes", type=positive_int, default=100, help="episodes per seed and spec (default 100)"),
    arg("--horizon", type=positive_int, default=None,
        help="episode length of every suite (default: each suite's own)"),
    arg("--backend", default="jax", choices=("jax", "gymnasium"),
        help="jax (compiled) or gymnasium (--policy module:factory whose factory(world) gives "
             "a numpy callable (obs, task) -> actions, run through the Gymnasium vector env)"),
    arg("--name", default=None, help="the policy's name in the tables"),
    arg("--out", default="bench", help="report directory (default bench/)"),
    arg("--no-progress", action="store_true", help="no progress lines"),
)
def bench_command(args: argparse.Namespace) -> int:
    enable_compilation_cache()
    from specrl_jax.benchmark import bench

    worlds = None if args.worlds is None else [w.strip() for w in args.worlds.split(",") if w.strip()]
    log = (lambda line: None) if args.no_progress else (lambda line: print(line, file=sys.stderr))
    report = bench.score(args.policy, worlds, args.suite, args.seeds, args.episodes,
                         backend=args.backend, horizon=args.horizon, out=args.out,
                         name=args.name, log=log)
    if args.no_progress or len(report.worlds) > 1:  # else its one line is already shown
        for line in report.lines():
            print(line)
    print(f"wrote {report.out}/: results.json, metrics.csv, tables.md, bench.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
