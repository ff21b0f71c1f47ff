"""`batch(env, B)`: auto-reset computed for the finished worlds only, the same semantics as the
per-world auto-reset, and much cheaper when resets are costly (exact LetterWorld maps)."""

import time

import jax
import jax.numpy as jnp
import numpy as np

import specrl_jax
from specrl_jax.envs import batch
from specrl_jax.envs.wrappers import AutoReset, BatchedEnv


def _step_case(num_done_max):
    env, params = specrl_jax.make("LetterLTL0-v0", max_steps=3)
    worlds = batch(env, 8, resets_per_step=2)
    raw = batch(env, 8, auto_reset=False)
    _, state = worlds.reset(jax.random.key(0), params)
    # stagger the clocks so that `num_done_max` worlds end at the next step
    state = state.replace(time=jnp.where(jnp.arange(8) < num_done_max, 2, 0).astype(jnp.int32))
    action = jnp.zeros(8, jnp.int32)
    key = jax.random.key(1)
    obs, new, _, terminated, truncated, info = jax.jit(worlds.step)(key, state, action, params)
    key_step, _ = jax.random.split(key)
    raw_obs, raw_state, *_ = raw.step(key_step, state, action, params)
    return new, obs, terminated | truncated, info, raw_obs, raw_state


def test_finished_worlds_restart_and_the_others_step_as_without_reset():
    for num_done in (2, 5):  # within resets_per_step, then the fallback for every world
        state, obs, done, info, raw_obs, raw_state = _step_case(num_done)
        done = np.asarray(done)
        assert done.sum() == num_done
        np.testing.assert_array_equal(np.asarray(state.time), np.where(done, 0, 1))
        live = ~done
        np.testing.assert_array_equal(np.asarray(state.agent)[live], np.asarray(raw_state.agent)[live])
        np.testing.assert_array_equal(np.asarray(obs["ap"])[live], np.asarray(raw_obs["ap"])[live])
        np.testing.assert_array_equal(np.asarray(info["final_observation"]["ap"]),
                                      np.asarray(raw_obs["ap"]))
        fresh = np.asarray(state.letters)[done]
        assert len({f.tobytes() for f in fresh}) == len(fresh)  # fresh, distinct maps
        assert not np.array_equal(fresh, np.asarray(raw_state.letters)[done])


def test_default_batch_is_far_cheaper_than_a_reset_per_world_per_step():
    """Exact LetterWorld resets cost ~0.3 ms each on a CPU; computing one per world per step
    made `batch(env, 256)` ~50x slower than computing them for finished worlds only (k = 2 of
    64 here)."""
    env, params = specrl_jax.make("LetterLTL0-v0")
    rates = {}
    for name, worlds in (("default", batch(env, 64)), ("per world", BatchedEnv(AutoReset(env), 64))):
        def run(state, key, worlds=worlds):
            def body(s, k):
                key_action, key_step = jax.random.split(k)
                out = worlds.step(key_step, s, worlds.sample_actions(key_action), params)
                return out[1], jnp.sum(out[3])
            return jax.lax.scan(body, state, jax.random.split(key, 10))
        run = jax.jit(run)
        state = worlds.reset(jax.random.key(0), params)[1]
        state, _ = run(state, jax.random.key(1))
        start = time.perf_counter()
        state, ended = run(state, jax.random.key(2))
        jax.block_until_ready(ended)
        rates[name] = 640 / (time.perf_counter() - start)
    assert rates["default"] > 8 * rates["per world"], rates


def _toy_reset(key):
    """A cheap fresh episode: a random obs vector and a random state."""
    key_obs, key_state = jax.random.split(key)
    return {"x": jax.random.uniform(key_obs, (2,))}, jax.random.randint(key_state, (), 1, 10**6)


def test_one_reset_done_for_one_world_a_batch_and_a_few_resets_per_step():
    """`reset_done` is the one auto-reset: one world (bool[]), a batch with a reset per world
    (the same as the one-world form per world), and the batch's k resets scattered into the
    finished worlds, falling back to a reset per world when more than k finish."""
    from specrl_jax.envs.wrappers import reset_done

    obs, state = {"x": -jnp.ones((5, 2))}, -jnp.arange(1, 6)
    key = jax.random.key(3)
    one = lambda d, k, o, s: reset_done(d, _toy_reset, k, o, s, {})[:2]
    done = jnp.array([True, False, True, False, False])
    per_world = jax.vmap(one)(done, jax.random.split(key, 5), obs, state)
    every = jax.jit(lambda d: reset_done(d, _toy_reset, key, obs, state, {"a": 1}))(done)
    jax.tree.map(np.testing.assert_array_equal, every[:2], per_world)
    assert every[2]["a"] == 1 and np.asarray(every[2]["final_observation"]["x"]).min() == -1
    few = jax.jit(lambda d: reset_done(d, _toy_reset, key, obs, state, {}, 2)[:2])
    new_obs, new_state = few(done)
    fresh_obs, fresh_state = jax.vmap(_toy_reset)(jax.random.split(key, 2))
    np.testing.assert_array_equal(np.asarray(new_state)[[0, 2]], fresh_state)
    np.testing.assert_array_equal(np.asarray(new_obs["x"])[[0, 2]], fresh_obs["x"])
    np.testing.assert_array_equal(np.asarray(new_state)[[1, 3, 4]], [-2, -4, -5])
    more = jnp.array([True, True, False, True, False])  # 3 > k = 2: a reset for every world
    jax.tree.map(np.testing.assert_array_equal, few(more),
                 jax.vmap(one)(more, jax.random.split(key, 5), obs, state))
