"""GCRL-LTL: network sizes, learning a tiny world through the task loop, the value function from
the trained policy's trajectories, the test-time agent on specs, and the 0.85 safety rule."""

import jax
import jax.numpy as jnp
import numpy as np

import specrl_jax
from specrl_jax import automata
from specrl_jax.baselines import gcrl
from tiny_learning import early_late, train_rows
from specrl_jax.baselines.ppo.networks import Categorical, PolicyOutput
from specrl_jax.envs.letter import LetterConfig, make_letter_world
from specrl_jax.eval import evaluate
from specrl_jax.tasks import TaskEnv


def _kernels(tree):
    return [x.shape for x in jax.tree.leaves(tree) if len(x.shape) == 2]


def test_networks_have_the_original_sizes():
    for env_id, width, head in (("LetterLTL0-v0", 1024 + 24, (256, 4)),
                                ("PointLTL0-v0", 80 + 24, (256, 4))):
        world, params = specrl_jax.make(env_id)
        method = gcrl.make_method(world, params, "letter" if env_id.startswith("L") else "zone")
        obs, _ = jax.eval_shape(method.env.reset, jax.random.key(0), method.init_task_params())
        one = jax.tree.map(lambda x: jax.ShapeDtypeStruct((1, *x.shape), x.dtype), obs)
        policy = jax.eval_shape(method.network.init, jax.random.key(0), one)
        shapes = gcrl.param_shapes(method, policy)
        dense = _kernels(shapes["policy"]["params"])
        # linear features as wide as the input, shared trunk 512-1024-256, then the heads
        assert dense[:4] == [(width, width), (width, 512), (512, 1024), (1024, 256)], dense
        assert head in dense[4:] and (256, 1) in dense[4:], dense
        state = sum(int(np.prod(x.shape)) for x in jax.tree.leaves(obs.parts))
        assert _kernels(shapes["gcvf"]) == [(state + 48, 1024)] + [(1024, 1024)] * 3 + [(1024, 1)]
        assert obs.goal.shape == (24,)
        if env_id.startswith("Point"):  # 4 direction primitives on the 12 robot sensors
            assert method.network.primitive_sensors == 12
            stacked = [x.shape for x in jax.tree.leaves(shapes["primitives"]) if len(x.shape) == 3]
            assert sorted(stacked) == sorted([(4, 12, 64), (4, 64, 64), (4, 64, 2)] * 1
                                             + [(4, 12, 64), (4, 64, 64), (4, 64, 1)]), stacked
        else:
            assert "primitives" not in shapes


def _tiny_world():
    config = LetterConfig(grid_size=5, letters=("a", "b"), counts=1)
    world, params = make_letter_world(config, max_steps=6)
    return world, world.with_map_bank(jax.random.key(0), params, num_maps=64)


def test_gcrl_learns_a_tiny_world_and_its_agent_follows_specs():
    world, params = _tiny_world()
    method = gcrl.make_method(world, params, trunk=(64, 64), value_features=(64, 64))
    updates = 80  # 60 left '!a U b' at 0.5 success on a 2-core CPU
    cfg = gcrl.ppo_config(num_envs=16, num_steps=24, total_timesteps=16 * 24 * updates,
                          update_epochs=4, num_minibatches=2)
    runner, rows = train_rows(gcrl, method, cfg, updates)
    first, last = early_late(rows)
    assert first < 0.4 and last > 0.6, (first, last)

    # the value function: trained on the critic's values of the other goal along successful runs
    vcfg = gcrl.ValueConfig(num_envs=32, num_steps=48, keep_prob=0.5, num_updates=300)
    data = gcrl.collect_value_data(method, runner.params, jax.random.key(2), vcfg)
    valid = np.asarray(data.valid)
    assert valid.sum() > 50 and not valid[np.arange(len(valid)), np.asarray(data.goal)].any()
    gcvf, stats = jax.jit(lambda p, k: gcrl.train_value_function(method, p, k, vcfg))(
        runner.params, jax.random.key(2))
    assert float(stats["loss_last"]) < 0.5 * float(stats["loss_first"]), stats

    # the agent on specs, through the evaluator (a 12-step horizon leaves room for two goals)
    policy = gcrl.make_policy(method.network, world.alphabet, world.obs_kinds,
                              value_network=method.value_network)
    formulas = ["F a", "F b", "!a U b", "F (a & F b)"]
    result = evaluate(policy, (world, params.replace(max_steps=12)), formulas, seeds=[1],
                      episodes_per_seed=64, policy_params={"policy": runner.params, "gcvf": gcvf})
    success = np.asarray(result.table.success).mean(axis=(0, 2))
    violation = np.asarray(result.table.violation).mean(axis=(0, 2))
    assert (success > 0.6).all() and violation[2] < 0.3, (success, violation)


class _Stub:
    """A network answering `GoalObs` batches with the logits and values per goal in `params`."""

    continuous = False
    primitive_sensors = 0

    def apply(self, params, obs):
        zeros = jnp.zeros(obs.goal_index.shape)
        return PolicyOutput(Categorical(params["logits"][obs.goal_index]),
                            params["values"][obs.goal_index], zeros, zeros)


class _PairStub:
    def apply(self, params, x):
        return jnp.full(x.shape[:-1], 0.5)


def test_agent_pursues_b_and_turns_away_from_a_above_the_threshold():
    """One step of the agent on '!a U b' with stub values V(s, a), V(s, b)."""
    world, params = specrl_jax.make("LetterLTL0-v0")
    spec = automata.compile_spec("!a U b", world.propositions, alphabet=world.alphabet)
    task = TaskEnv(world, automata.stack([spec]))
    obs, state = task.reset(jax.random.key(0), params, spec_index=0)
    logits = np.zeros((12, 4), np.float32)
    logits[0] = [0, 0, 5, 1]  # toward 'a': action 2, least likely 0
    logits[1] = [0, 3, 4, 1]  # toward 'b': action 2 best, then 1
    policy = gcrl.make_policy(_Stub(), world.alphabet, world.obs_kinds, value_network=_PairStub())

    @jax.jit
    def act(values):
        stub = {"logits": jnp.asarray(logits), "values": jnp.zeros(12).at[:2].set(values)}
        net = {"policy": stub, "gcvf": None}
        carry = policy.init(net, obs, state, jax.random.key(1))
        return policy.apply(net, obs, state, carry, jax.random.key(2))

    (action, slot), carry = act(jnp.array([0.5, 0.7]))  # 'a' is not close: the goal's best action
    avoid = np.asarray(carry.avoid)
    assert int(carry.goal) == 1 and avoid[0] and not avoid[1:].any()
    assert (int(action), int(slot)) == (2, -1)
    # 'a' closer than the goal and above 0.85: the goal's best move other than toward 'a'
    assert int(act(jnp.array([0.9, 0.7]))[0][0]) == 1
    assert int(act(jnp.array([0.8, 0.7]))[0][0]) == 2  # closer than the goal but under 0.85
    assert int(act(jnp.array([0.9, 0.95]))[0][0]) == 2  # above 0.85 but the goal is closer
