"""GCRL-LTL's direction primitives on a stub plane world: the training reward against a
hand-computed value, the auto-reset at the primitives' horizon, the hierarchical world's action,
the safety rule summing two primitives, and the primitives kept in the run directory and in the
disk cache."""

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax import cache
from specrl_jax.baselines import gcrl
from specrl_jax.baselines.gcrl import primitives as prim
from specrl_jax.baselines.ppo.networks import Categorical, PolicyOutput
from specrl_jax.envs.spaces import Box


@struct.dataclass
class _Params:
    max_steps: int = 1000


@struct.dataclass
class _Physics:
    agent_pos: jax.Array  # float32[3]


@struct.dataclass
class _State:
    physics: _Physics
    time: jax.Array


class _Robot:
    ego_size = 2


class _PlaneWorld:
    """A point moved by its action (metres per step), 0.5 s per step; `ego` = [x, y, wall x4]."""

    robot = _Robot()
    frame_dt = 0.5
    action_space = Box(-1.0, 1.0, (2,))

    def _obs(self, pos):
        return {"ego": jnp.concatenate([pos[:2], jnp.full(4, 7.0)])}

    def reset(self, key, params):
        pos = jnp.concatenate([jax.random.uniform(key, (2,)), jnp.zeros(1)])
        return self._obs(pos), _State(_Physics(pos), jnp.int32(0))

    def step(self, key, state, action, params):
        pos = state.physics.agent_pos + jnp.concatenate([action, jnp.zeros(1)])
        time = state.time + 1
        terminated = jnp.abs(pos[0]) > 50.0
        truncated = (time >= params.max_steps) & ~terminated
        nxt = _State(_Physics(pos), time)
        info = {"propositions": jnp.zeros(1, bool)}
        return self._obs(pos), nxt, jnp.float32(0), terminated, truncated, info


def test_direction_reward_is_speed_along_minus_five_hundredths_across():
    env = prim.direction_env(_PlaneWorld(), _Params())
    sensors, state = env.reset(jax.random.key(0), jnp.int32(0))
    np.testing.assert_allclose(sensors, state.physics.agent_pos[:2])  # the wall sensor is left out
    action = jnp.array([0.3, -0.2])  # velocity (0.6, -0.4) m/s
    for direction, want in ((0, 0.6 - 0.05 * 0.4), (1, -0.6 - 0.05 * 0.4),
                            (2, -0.4 - 0.05 * 0.6), (3, 0.4 - 0.05 * 0.6)):
        _, _, result = env.step(jax.random.key(1), state, action, jnp.int32(direction))
        np.testing.assert_allclose(float(result.reward), want, rtol=1e-5)
    # the actions are clipped to the box, and the episode resets at the primitives' horizon
    _, _, result = env.step(jax.random.key(1), state, jnp.array([3.0, 0.0]), jnp.int32(0))
    np.testing.assert_allclose(float(result.reward), 2.0, rtol=1e-5)
    late = state.replace(time=jnp.int32(prim.HORIZON - 1))
    sensors, after, result = env.step(jax.random.key(2), late, action, jnp.int32(0))
    assert bool(result.truncated) and int(after.time) == 0
    np.testing.assert_allclose(result.final_obs, state.physics.agent_pos[:2] + action, rtol=1e-6)


def _primitives(means):
    """Four primitives whose mean action is `means[k]` whatever the sensors."""
    params = prim.init_primitives(_PlaneWorld(), jax.random.key(0))
    head = params["params"]["Dense_0"]
    params["params"]["Dense_0"] = {"kernel": jnp.zeros_like(head["kernel"]),
                                   "bias": jnp.asarray(means, jnp.float32)}
    return params


def test_primitive_world_steps_the_chosen_primitive_times_the_temperature():
    means = [[0.5, 0.0], [-0.9, 0.0], [0.0, 0.2], [0.0, -0.4]]
    world = prim.PrimitiveWorld(_PlaneWorld(), _primitives(means), temperature=1.25)
    assert world.action_space.n == 4
    _, state = world.reset(jax.random.key(0), _Params())
    for k, want in enumerate([[0.625, 0.0], [-1.0, 0.0], [0.0, 0.25], [0.0, -0.5]]):
        _, after, *_ = world.step(jax.random.key(1), state, jnp.int32(k), _Params())
        moved = after.world.physics.agent_pos[:2] - state.world.physics.agent_pos[:2]
        np.testing.assert_allclose(moved, want, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(after.sensors, after.world.physics.agent_pos[:2])


def test_safety_rule_sums_the_safe_and_the_goal_primitive():
    """Goal 1, danger 0 (above 0.85 and the goal's value): the primitive least likely toward 0
    plus the goal's best primitive other than the one most likely toward 0, at temperature 1.5."""
    means = [[0.5, 0.0], [0.0, 0.5], [0.3, 0.3], [0.0, -0.5]]
    primitives = _primitives(means)
    network = gcrl.GCRLNetwork(4, primitive_sensors=2)
    logits = jnp.array([[0.0, 1.0, 5.0, 2.0],  # toward the danger: primitive 2; least likely 0
                        [0.0, 3.0, 4.0, 1.0]])  # toward the goal: 2 best, then 1
    sensors = jnp.zeros(2)
    for values, want in (([0.9, 0.7], [0.75, 0.75]), ([0.8, 0.7], [0.45, 0.45])):
        out = PolicyOutput(Categorical(logits), jnp.asarray(values), jnp.zeros(2), jnp.zeros(2))
        action = gcrl.safe_action(network, out, jnp.int32(1), jnp.array([True, False]), 0.85,
                                  True, jax.random.key(0), primitives, sensors)
        np.testing.assert_allclose(action, want, atol=1e-6)


def test_safety_rule_scales_the_sum_of_the_two_primitives_not_each():
    """The original steps `(a_safe + a_goal) * 1.5` (each primitive's action clipped to the box
    first, the world clips the result): a saturating primitive cannot cancel the other."""
    means = [[0.9, -0.2], [0.0, 0.0], [0.6, -0.4], [-0.5, 0.8]]  # safe 0, goal 3, mode 2
    network = gcrl.GCRLNetwork(4, primitive_sensors=2)
    logits = jnp.array([[0.0, 1.0, 5.0, 2.0],  # toward the danger: 2; least likely 0
                        [0.0, 1.0, 4.0, 3.0]])  # toward the goal: 2 (blocked), then 3
    out = PolicyOutput(Categorical(logits), jnp.array([0.9, 0.7]), jnp.zeros(2), jnp.zeros(2))
    action = gcrl.safe_action(network, out, jnp.int32(1), jnp.array([True, False]), 0.85,
                              True, jax.random.key(0), _primitives(means), jnp.zeros(2))
    # (0.9 - 0.5) * 1.5 = 0.6 and (-0.2 + 0.8) * 1.5 = 0.9; scaling each first gives 0.25, 0.7
    np.testing.assert_allclose(action, [0.6, 0.9], atol=1e-6)
    # another temperature scales the sum, and the goal's own primitive below the threshold
    for values, want in (([0.9, 0.7], [0.5, 0.75]), ([0.8, 0.7], [0.75, -0.5])):
        out = out._replace(value=jnp.asarray(values))
        action = gcrl.safe_action(network, out, jnp.int32(1), jnp.array([True, False]), 0.85,
                                  True, jax.random.key(0), _primitives(means), jnp.zeros(2),
                                  temperature=1.25)
        np.testing.assert_allclose(action, want, atol=1e-6)


def test_train_primitives_runs_the_four_directions_through_the_run_driver():
    """The four primitives train side by side on the driver's seed axis: parameters with a
    leading axis of 4, finite, one logged line of speeds per direction."""
    lines = []
    cfg = prim.ppo_config(8 * 32 * 3, num_envs=8, num_steps=32, num_minibatches=2, update_epochs=2)
    params = prim.train_primitives(_PlaneWorld(), _Params(), jax.random.key(0), cfg, lines.append)
    leaves = jax.tree.leaves(params)
    assert all(leaf.shape[0] == len(prim.DIRECTIONS) for leaf in leaves)
    assert all(bool(jnp.all(jnp.isfinite(leaf))) for leaf in leaves)
    assert len(lines) == 1 and lines[0].startswith("direction primitives: 3 updates")


def test_a_run_directory_keeps_the_primitives_for_a_resumed_run(monkeypatch, tmp_path):
    """`prepare_training` with a saved file trains the primitives once: a resumed run reads
    them back and acts through the same parameters."""
    import specrl_jax

    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path / "cache"))  # the fake primitives stay here
    world, params = specrl_jax.make("PointLTL0-v0")
    method = gcrl.make_method(world, params, trunk=(8,), value_features=(8,))
    trained = jax.tree.map(lambda x: x + 1.0, method.primitives)
    calls = []
    monkeypatch.setattr(prim, "train_primitives", lambda *args: calls.append(args) or trained)
    cfg = gcrl.ppo_config("zone", total_timesteps=1500)
    saved = tmp_path / "prepared.msgpack"
    first = gcrl.prepare_training(method, jax.random.key(0), cfg, saved=saved)
    resumed = gcrl.prepare_training(method, jax.random.key(0), cfg, saved=saved)
    assert len(calls) == 1 and saved.exists()
    for a, b, c in zip(*map(jax.tree.leaves, (trained, first.primitives, resumed.primitives))):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)


def test_an_identical_training_reads_the_primitives_from_the_disk_cache(monkeypatch, tmp_path):
    """`cached_primitives` trains once per distinct input: an identical call reads the
    primitives back, equal to those trained, and says so; another key, world params or PPO
    setting trains again, and a world defined outside the package trains every time."""
    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path))
    template = prim.init_primitives(_PlaneWorld(), jax.random.key(0))
    trained = []

    def train(world, params, key, config, log):  # stands for the PPO run (tested above)
        trained.append(key)
        leaves, structure = jax.tree.flatten(template)
        keys = jax.random.split(jax.random.key(len(trained)), len(leaves))
        return jax.tree.unflatten(structure, [jax.random.normal(k, x.shape, x.dtype)
                                              for k, x in zip(keys, leaves)])

    monkeypatch.setattr(prim, "train_primitives", train)
    in_package = cache.in_package
    monkeypatch.setattr(cache, "in_package", lambda *objects: True)  # as a world of the package
    cfg = prim.ppo_config(1000)
    lines = []
    first, again = (prim.cached_primitives(_PlaneWorld(), _Params(), jax.random.key(0), cfg,
                                           template, lines.append) for _ in range(2))
    assert len(trained) == 1 and lines[-1].startswith("direction primitives read from the cache")
    assert jax.tree.structure(again) == jax.tree.structure(template)
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(again)):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    for world_params, key, config in ((_Params(), jax.random.key(1), cfg),
                                      (_Params(max_steps=999), jax.random.key(0), cfg),
                                      (_Params(), jax.random.key(0), prim.ppo_config(2000))):
        prim.cached_primitives(_PlaneWorld(), world_params, key, config, template, lines.append)
    assert len(trained) == 4
    monkeypatch.setattr(cache, "in_package", in_package)
    for _ in range(2):
        prim.cached_primitives(_PlaneWorld(), _Params(), jax.random.key(0), cfg, template)
    assert len(trained) == 6
