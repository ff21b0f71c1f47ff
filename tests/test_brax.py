"""The Brax adapter (`specrl_jax.brax`) against Brax's own wrappers and trainers, on a tiny
continuous world through the task loop with GenZ-LTL's continual subgoals; the runnable example
on PointLTL0-v0 for a couple of PPO iterations."""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from specrl_jax.baselines import genz
from specrl_jax.envs.base import Env
from specrl_jax.envs.spaces import Box, Dict

brax_envs = pytest.importorskip("brax.envs", reason="Brax is the optional extra 'brax'")
from brax.envs.wrappers import training as brax_training  # noqa: E402

from specrl_jax.brax import METRICS, BraxTaskEnv, wrap_for_training  # noqa: E402

NUM_PROPS, RADIUS, SPEED = 4, 0.35, 0.3


@dataclass(frozen=True)
class DotConfig:
    horizon: int = 8


@struct.dataclass
class DotParams:
    max_steps: int = 8


@struct.dataclass
class DotState:
    centres: jax.Array  # float32[P, 2], region centres in [-1, 1]^2
    pos: jax.Array  # float32[2]
    time: jax.Array  # int32[]


class DotWorld(Env):
    """A point in [-1, 1]^2 moved by `SPEED * action`; four discs; label: the first disc the
    point is in (one-hot or none). obs: `ap` the offset to each centre `[P, 2]`, `ego` the
    position."""

    propositions = ("blue", "green", "magenta", "yellow")
    obs_kinds = {"ap": "lidar", "ego": "vector"}

    def __init__(self, config: DotConfig = DotConfig()):
        self.config = config

    @property
    def default_params(self) -> DotParams:
        return DotParams(self.config.horizon)

    @property
    def action_space(self) -> Box:
        return Box(-2.0, 2.0, (2,), jnp.float32)

    @property
    def observation_space(self) -> Dict:
        return Dict({"ap": Box(-2, 2, (NUM_PROPS, 2)), "ego": Box(-1, 1, (2,))})

    @property
    def alphabet(self) -> jax.Array:
        return jnp.concatenate([jnp.zeros((1, NUM_PROPS), bool), jnp.eye(NUM_PROPS, dtype=bool)])

    def _obs(self, state):
        return {"ap": state.centres - state.pos, "ego": state.pos}

    def _label(self, state):
        inside = jnp.linalg.norm(state.centres - state.pos, axis=-1) < RADIUS
        return inside & (jnp.cumsum(inside) == 1)

    def reset_env(self, key, params):
        centres = jax.random.uniform(key, (NUM_PROPS, 2), minval=-1.0, maxval=1.0)
        return self.reset_to(key, {"centres": centres}, params)

    def reset_to(self, key, layout, params):
        state = DotState(jnp.asarray(layout["centres"], jnp.float32), jnp.zeros(2),
                         jnp.zeros((), jnp.int32))
        return self._obs(state), state

    def step_env(self, key, state, action, params):
        pos = jnp.clip(state.pos + SPEED * action, -1.0, 1.0)
        state = state.replace(pos=pos, time=state.time + 1)
        info = {"propositions": self._label(state)}
        return self._obs(state), state, jnp.zeros(()), jnp.zeros((), bool), info

    def layout(self, state):
        return {"centres": state.centres, "pos": state.pos}


def dot_env(horizon: int = 8) -> BraxTaskEnv:
    world = DotWorld(DotConfig(horizon))
    method = genz.make_method(world, world.default_params, "zone")
    return BraxTaskEnv(method.env.task, method.env.params)


def flat(obs) -> np.ndarray:
    """The adapter's flattening, written out: every leaf in sorted-key order."""
    return np.concatenate([np.ravel(obs[name]) for name in sorted(obs)])


def test_adapter_matches_the_task_loop_step_by_step():
    """Reset and step are the task loop's (same keys), actions scaled [-1, 1] -> the world's box,
    the observation is GenZ's reduced one flattened, the reward the loop's progress reward."""
    env = dot_env()
    task, params, source_params = env.task, env.params, env.source_params
    state = jax.jit(env.reset)(jax.random.PRNGKey(3))
    key_reset, key = jax.random.split(jax.random.PRNGKey(3))
    obs, task_state = task.reset(key_reset, params, None, source_params)
    np.testing.assert_allclose(state.obs, flat(obs))
    assert env.observation_size == state.obs.shape[0] == 2 + 2 * 2  # ego + pooled reach, avoid
    assert env.action_size == 2
    step = jax.jit(env.step)
    actions = jax.random.uniform(jax.random.PRNGKey(4), (6, 2), minval=-1.0, maxval=1.0)
    for action in actions:
        state = step(state, action)
        key, key_step = jax.random.split(key)
        obs, task_state, reward, terminated, truncated, info = task.step(
            key_step, task_state, 2.0 * action, params, False, source_params)
        np.testing.assert_allclose(state.obs, flat(obs), rtol=1e-6)
        assert float(state.reward) == float(reward)
        assert float(state.done) == float(terminated | truncated)
        assert float(state.info["truncation"]) == float(truncated)
        assert float(state.metrics["reaches"]) == float(info["progress"])
        assert float(state.metrics["violations"]) == float(info["violation"])
    assert set(state.metrics) == set(METRICS)


def test_wrapped_env_resets_to_fresh_layouts_and_tasks_and_counts_episodes():
    """Under `wrap_for_training` (Brax's VmapWrapper + episode metrics) every ended episode
    restarts on a new layout with a new subgoal; `truncation` marks the horizon only; episode
    metrics sum over the episode that just ended."""
    horizon, batch = 5, 8
    env = wrap_for_training(dot_env(), episode_length=horizon)
    state = jax.jit(env.reset)(jax.random.split(jax.random.PRNGKey(0), batch))
    step = jax.jit(env.step)
    key = jax.random.PRNGKey(1)
    fresh_layouts = fresh_tasks = ends = 0
    running = np.zeros(batch)
    for t in range(3 * horizon):
        key, key_action = jax.random.split(key)
        before = state.pipeline_state.task
        state = step(state, jax.random.uniform(key_action, (batch, 2), minval=-1, maxval=1))
        after = state.pipeline_state.task
        done = np.asarray(state.done, bool)
        running = running + np.asarray(state.reward)
        np.testing.assert_allclose(state.info["episode_metrics"]["sum_reward"], running, rtol=1e-6)
        assert np.all(np.asarray(state.info["truncation"], bool) <= done)
        truncated = np.asarray(state.info["truncation"], bool)
        at_horizon = np.asarray(state.info["steps"]) >= horizon
        assert np.all(truncated <= at_horizon) and np.all(at_horizon <= done)
        moved = np.any(np.asarray(before.env_state.centres != after.env_state.centres), axis=(1, 2))
        np.testing.assert_array_equal(moved, done)  # a layout changes exactly at episode ends
        np.testing.assert_array_equal(np.asarray(after.time)[done], 0)
        changed = np.any(np.asarray(before.task.reach != after.task.reach), axis=(1, 2))
        fresh_layouts += int(moved.sum())
        fresh_tasks += int(changed[done].sum())
        ends += int(done.sum())
        running[done] = 0.0
    assert ends >= batch * 2 and fresh_layouts == ends
    assert fresh_tasks >= ends // 2  # a fresh draw repeats the old subgoal only by chance


def test_brax_default_wrapper_with_its_cached_first_state_is_refused():
    env = brax_training.wrap(dot_env(), episode_length=5)
    state = env.reset(jax.random.split(jax.random.PRNGKey(0), 2))
    with pytest.raises(ValueError, match="wrap_env_fn=specrl_jax.brax.wrap_for_training"):
        env.step(state, jnp.zeros((2, 2)))


def test_clear_errors_for_discrete_worlds_and_unsupported_wrapper_options():
    from specrl_jax.envs.registry import make

    letter, params = make("LetterLTL0-v0")
    method = genz.make_method(letter, params, "letter")
    with pytest.raises(ValueError, match="continuous actions"):
        BraxTaskEnv(method.env.task)
    with pytest.raises(ValueError, match="action_repeat must be 1"):
        wrap_for_training(dot_env(), 5, action_repeat=2)
    with pytest.raises(TypeError, match="TaskEnv"):
        BraxTaskEnv(letter)


def test_brax_ppo_trains_and_evaluates_through_the_adapter():
    """One Brax PPO run of a few iterations: training and evaluation run on the adapter as Brax's
    trainer calls it, and the evaluator reports the adapter's episode metrics."""
    from brax.training.agents.ppo import train as ppo

    progress = []
    make_policy, params, metrics = ppo.train(
        dot_env(), num_timesteps=2 * 8 * 4 * 2, episode_length=8, wrap_env_fn=wrap_for_training,
        num_envs=8, batch_size=8, num_minibatches=2, unroll_length=4, num_updates_per_batch=1,
        num_evals=2, num_eval_envs=8, seed=0, progress_fn=lambda step, m: progress.append(m),
    )
    assert len(progress) == 2
    final = progress[-1]
    for name in ("eval/episode_reward", "eval/episode_reaches", "eval/episode_violations",
                 "eval/avg_episode_length"):
        assert np.isfinite(final[name]), name
    assert 1.0 <= final["eval/avg_episode_length"] <= 8.0
    # reward = reaches - violations in every evaluation episode (the loop's progress reward)
    assert final["eval/episode_reward"] == pytest.approx(
        final["eval/episode_reaches"] - final["eval/episode_violations"], abs=1e-5)
    policy = make_policy(params, deterministic=True)
    action, _ = policy(jnp.zeros((3, dot_env().observation_size)), jax.random.PRNGKey(0))
    assert action.shape == (3, 2)


def test_the_example_runs_a_few_iterations(tmp_path):
    """examples/brax_ppo_point.py end to end at a tiny size (Brax PPO trains, evaluates and writes
    its success-rate curve), on the dot world registered under an ID as a user's world would be:
    the example's code path without compiling MJX Point under Brax (the adapter's steps on MJX
    worlds are the task loop's, tested with them). One evaluation, after training: Brax compiles
    its evaluator again for each later one."""
    from specrl_jax.envs import registry

    path = Path(__file__).parents[1] / "examples" / "brax_ppo_point.py"
    spec = importlib.util.spec_from_file_location("brax_ppo_point", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["brax_ppo_point"] = module
    spec.loader.exec_module(module)
    registry.register("DotLTL-v0", lambda: (DotWorld(DotConfig(8)), DotParams(8)))
    try:
        rows = module.main(["--env", "DotLTL-v0", "--num-envs", "4", "--unroll-length", "4",
                            "--num-timesteps", "64", "--num-evals", "1", "--episode-length", "8",
                            "--out", str(tmp_path)])
    finally:
        registry.unregister("DotLTL-v0")
    assert len(rows) == 1 and 0.0 <= rows[0]["success_rate"] <= 1.0
    assert rows[0]["env_steps"] >= 64  # evaluated after the training steps
    record = json.loads((tmp_path / "brax_ppo_point.json").read_text())
    assert record["env"] == "DotLTL-v0" and record["evals"] == rows
