"""GCRL-LTL: network sizes, learning a tiny world through the task loop, the value function from
the trained policy's trajectories, the test-time agent on specs, and the 0.85 safety rule."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny_learning import early_late, train_rows

import specrl_jax
from specrl_jax import automata
from specrl_jax.baselines import gcrl
from specrl_jax.baselines.ppo.networks import Categorical, DiagGaussian, PolicyOutput
from specrl_jax.envs.letter import LetterConfig, make_letter_world
from specrl_jax.eval import evaluate
from specrl_jax.eval.evaluate import record_episodes
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
    runner, rows = train_rows(gcrl, method, cfg, updates, optimised=False)  # level 0: 46 -> 38 s
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


def test_gcvf_seeds_run_side_by_side_unless_their_rollouts_are_too_large(monkeypatch):
    cfg = gcrl.ValueConfig(num_envs=128, num_steps=1000, num_updates=1)
    for env_id, options, expected in (("PointLTL0-v0", {}, 5),
                                      ("PointLTL0Vision-v0", {"image_size": 64}, 1)):
        world, params = specrl_jax.make(env_id, **options)
        method = gcrl.make_method(world, params, "zone")
        assert gcrl.gcvf_seeds_at_once(method, cfg, 5) == expected, env_id

    # one seed at a time fits the same value functions as all side by side
    world, params = _tiny_world()
    method = gcrl.make_method(world, params, trunk=(16,), value_features=(16,))
    obs, _ = method.env.reset(jax.random.key(0), method.init_task_params())
    one = jax.tree.map(lambda x: x[None], obs)
    policy = jax.vmap(lambda k: method.network.init(k, one))(jax.random.split(jax.random.key(1), 2))
    ppo = gcrl.ppo_config(total_timesteps=3000)
    lines = []
    together = gcrl.finish_training(method, policy, jax.random.key(3), ppo, log=lines.append)
    monkeypatch.setattr(gcrl, "GCVF_BATCH_BYTES", 1)
    apart = gcrl.finish_training(method, policy, jax.random.key(3), ppo, log=lines.append)
    side_by_side = [line.split("(")[1].split()[0] for line in lines if line.startswith("GCVF (")]
    assert side_by_side == ["2", "1"], lines
    for a, b in zip(jax.tree.leaves(together["gcvf"]), jax.tree.leaves(apart["gcvf"]), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    assert not np.allclose(jax.tree.leaves(together["gcvf"])[0][0],
                           jax.tree.leaves(together["gcvf"])[0][1])  # the seeds differ


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


def test_as_coded_planner_ignores_values_and_avoids_every_proposition_leaving_the_state():
    """'F a & F b' with V(s, b) far above V(s, a): the intended search goes to b first and avoids
    nothing; the original's code (costs `min(1 - V, 0)`) takes the first found order, a, and
    avoids both a and b (the negated propositions of the self-loop)."""
    world, params = specrl_jax.make("LetterLTL0-v0")
    spec = automata.compile_spec("F a & F b", world.propositions, alphabet=world.alphabet)
    task = TaskEnv(world, automata.stack([spec]))
    obs, state = task.reset(jax.random.key(0), params, spec_index=0)
    stub = {"logits": jnp.zeros((12, 4)), "values": jnp.zeros(12).at[:2].set(jnp.array([0.2, 0.9]))}
    net = {"policy": stub, "gcvf": None}
    for planner, goal, avoided in (("intended", 1, []), ("as_coded", 0, [0, 1])):
        policy = gcrl.make_policy(_Stub(), world.alphabet, world.obs_kinds,
                                  value_network=_PairStub(), planner=planner)
        carry = policy.init(net, obs, state, jax.random.key(1))
        _, carry = policy.apply(net, obs, state, carry, jax.random.key(2))
        assert int(carry.goal) == goal, planner
        assert np.nonzero(np.asarray(carry.avoid))[0].tolist() == avoided, planner
    with pytest.raises(ValueError, match="as_coded"):
        gcrl.make_policy(_Stub(), world.alphabet, world.obs_kinds, planner="original")


class _LetterOracle:
    """A hand-made GCRL network on a full-view LetterWorld: for goal g, a large logit on the
    move toward letter g (rows first) and the value `1 - 0.1 * distance` to it."""

    continuous = False
    primitive_sensors = 0

    def apply(self, params, obs):
        grid = obs.parts["grid"]  # [..., V, V, L + 1]: letter channels, then the agent
        v = grid.shape[-2]
        channel = jnp.take_along_axis(grid, obs.goal_index[..., None, None, None], axis=-1)
        cell = jnp.argmax(channel.reshape(*channel.shape[:-3], -1), axis=-1)
        di, dj = cell // v - v // 2, cell % v - v // 2
        move = jnp.where(di < 0, 0, jnp.where(di > 0, 1, jnp.where(dj < 0, 2, 3)))
        value = 1.0 - 0.1 * (jnp.abs(di) + jnp.abs(dj))
        zeros = jnp.zeros_like(value)
        return PolicyOutput(Categorical(5.0 * jax.nn.one_hot(move, 4)), value, zeros, zeros)


def test_agent_visits_acceptance_on_infinite_specs_and_takes_the_persistence_jump():
    """The test-time agent with an oracle network on the tiny world: `GF a & GF b` alternates
    the letters (accepting visits, no violation); on `F G !a` the plan's epsilon jump is taken
    and 'a' kept away from afterwards (with no goal the agent follows the policy of proposition
    0, here 'a' itself, so the 0.85 rule is what turns it away, one cell before the letter)."""
    world, params = _tiny_world()
    params = params.replace(max_steps=30)
    policy = gcrl.make_policy(_LetterOracle(), world.alphabet, world.obs_kinds,
                              value_network=_PairStub())
    net = {"policy": None, "gcvf": None}
    formulas = ["GF a & GF b", "F G !a"]
    table = evaluate(policy, (world, params), formulas, seeds=[0], episodes_per_seed=8,
                     policy_params=net).table
    visits, violation = np.asarray(table.num_accepting)[0], np.asarray(table.violation)[0]
    assert not violation.any(), violation
    # on a 5x5 torus each letter is at most 4 moves from the other: an a-b round trip per 8 steps
    assert (visits[0] >= 30 // 8).all(), visits[0]
    assert (visits[1] > 0).all(), visits[1]

    spec = automata.compile_spec("F G !a", world.propositions, alphabet=world.alphabet)
    assert bool(automata.has_epsilon(spec, spec.init))
    jumped = int(spec.epsilon[spec.init, 0])
    task = TaskEnv(world, automata.stack([spec]))
    states, _alive = record_episodes(policy, task, params, jax.random.split(jax.random.key(3), 8),
                                    jnp.zeros(8, jnp.int32), policy_params=net)
    q = np.asarray(states.q)
    assert (q[:, -1] == jumped).all() and (q[:, 0] != jumped).all(), q


def test_gaussian_head_safety_rule_turns_from_the_worst_avoided_proposition_above_085():
    """The arm's rule: when the most dangerous avoided proposition's value exceeds 0.85 and the
    goal's (the original's condition), the goal's mean action minus that proposition's,
    clipped to the box; otherwise the goal's mean. No goal: away from the danger alone, and
    with no danger the first proposition not avoided is pursued."""
    network = gcrl.GCRLNetwork(2, continuous=True)
    means = jnp.array([[0.6, 0.2], [0.5, -0.4], [-0.3, 0.9], [0.0, 0.0]])
    avoid = jnp.array([True, False, True, False])
    goal = jnp.int32(1)
    rule = jax.jit(lambda values, goal: gcrl.safe_action(
        network, PolicyOutput(DiagGaussian(means, jnp.full((4, 2), 0.1)), values, values, values),
        goal, avoid, gcrl.VALUE_THRESHOLD, True, jax.random.key(0)))
    cases = [
        ([0.9, 0.7, 0.1, 0.99], goal, [-0.1, -0.6]),  # away from 0; 3 is not avoided
        ([0.9, 0.7, 0.95, 0.1], goal, [0.8, -1.0]),  # the worst is 2; clipped at -1
        ([0.84, 0.7, 0.1, 0.1], goal, [0.5, -0.4]),  # closer than the goal but under 0.85
        ([0.9, 0.95, 0.1, 0.1], goal, [0.5, -0.4]),  # above 0.85 but the goal is closer
        ([0.9, 0.2, 0.1, 0.1], jnp.int32(-1), [-0.6, -0.2]),  # no goal: away only
        # no goal and no danger: toward the first proposition not avoided (1), never toward 0
        ([0.5, 0.2, 0.1, 0.1], jnp.int32(-1), [0.5, -0.4]),
    ]
    for values, g, want in cases:
        np.testing.assert_allclose(rule(jnp.asarray(values), g), want, atol=1e-6,
                                   err_msg=str(values))
