"""GenZ-LTL and DeepLTL through the task loop: learning on a tiny world, observation reduction,
encoders, test-time agents."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from tiny_learning import early_late, train_rows

import specrl_jax
from specrl_jax import automata
from specrl_jax.baselines import deepltl, genz
from specrl_jax.envs.letter import LetterConfig, make_letter_world
from specrl_jax.eval import evaluate
from specrl_jax.tasks import TaskEnv


def _tiny_world():
    # 5x5 torus, one 'a' and one 'b', 6-step episodes: a random walk rarely reaches its subgoal.
    world, params = make_letter_world(LetterConfig(grid_size=5, letters=("a", "b"), counts=1), max_steps=6)
    return world, world.with_map_bank(jax.random.key(0), params, num_maps=64)


def _learning(module, method, cfg, updates, optimised=True):
    return early_late(train_rows(module, method, cfg, updates, optimised)[1])


def test_genz_learns_to_reach_on_a_tiny_letter_world_through_the_task_loop():
    world, params = _tiny_world()
    method = genz.make_method(world, params)  # subgoals: reach one letter, avoid the other or none
    cfg = genz.ppo_config(num_envs=16, num_steps=24, total_timesteps=16 * 24 * 40, update_epochs=4,
                          num_minibatches=2)
    # at the suite's level 0: the training compiles several times faster and runs no slower
    first, last = _learning(genz, method, cfg, 40, optimised=False)
    assert first < 0.4 and last > 0.6, (first, last)


def test_deepltl_learns_reach_avoid_on_a_tiny_letter_world_through_the_task_loop():
    world, params = _tiny_world()
    method = deepltl.make_method(world, params)  # curriculum stage 0: reach one, avoid the other
    cfg = deepltl.ppo_config(num_envs=16, num_steps=24, total_timesteps=16 * 24 * 75,
                             update_epochs=4, num_minibatches=2)
    # stage 0 holds until its 0.95 is met; at the suite's level 0 (43 -> 31 s on a 2-core CPU)
    first, last = _learning(deepltl, method, cfg, 75, optimised=False)
    assert first < 0.4 and last > 0.6, (first, last)


KINDS = {"ap": "grid", "ego": "grid"}


def test_reduced_observation_marks_reach_avoid_and_agent():
    ap = np.zeros((3, 3, 3), np.uint8)
    ap[0, 0, 0] = ap[0, 1, 1] = ap[2, 2, 2] = 1
    ego = np.zeros((3, 3, 1), np.uint8)
    ego[1, 1] = 1
    image = genz.reduce_observation(
        {"ap": jnp.asarray(ap), "ego": jnp.asarray(ego)}, KINDS,
        jnp.array([True, False, False]), jnp.array([False, True, False]),
    )["grid"][..., 0]
    expected = np.zeros((3, 3))
    expected[0, 0], expected[0, 1], expected[1, 1] = 1.0, 0.5, 0.2
    np.testing.assert_allclose(image, expected)
    ap[1, 1, 0] = 1  # standing on a reach letter: the agent is drawn on top
    image = genz.reduce_observation(
        {"ap": jnp.asarray(ap), "ego": jnp.asarray(ego)}, KINDS,
        jnp.array([True, False, False]), jnp.array([False, True, False]),
    )["grid"][..., 0]
    assert np.isclose(float(image[1, 1]), 0.2)


def test_reduced_lidar_observation_pools_reach_and_avoid_sets_after_the_sensors():
    """Zone worlds (GenZ-LTL's `pre_process_obs_zones`): [sensors, max LiDAR of the reach
    colours, max LiDAR of the avoid colours], zeros for an empty set."""
    rng = np.random.default_rng(0)
    ap = rng.random((4, 16)).astype(np.float32)
    ego = rng.random(16).astype(np.float32)
    obs = {"ap": jnp.asarray(ap), "ego": jnp.asarray(ego)}
    kinds = {"ap": "lidar", "ego": "vector"}
    reach, avoid = jnp.array([False, True, False, False]), jnp.array([True, False, True, False])
    vec = np.asarray(genz.reduce_observation(obs, kinds, reach, avoid)["vector"])
    np.testing.assert_allclose(vec, np.concatenate([ego, ap[1], np.maximum(ap[0], ap[2])]))
    none = np.asarray(genz.reduce_observation(obs, kinds, reach, jnp.zeros(4, bool))["vector"])
    np.testing.assert_allclose(none[32:], 0.0)


def test_methods_refuse_a_world_whose_observation_kind_has_no_encoder():
    world, params = specrl_jax.make("LetterLTL0-v0")

    class Sonar(type(world)):
        obs_kinds = {"ap": "sonar", "ego": "grid"}

    odd = Sonar(world.config)
    for module in (genz, deepltl):
        with pytest.raises(ValueError, match="no observation encoder for {'ap': 'sonar'}"):
            module.make_method(odd, params)


def _genz_setup(formula, replan_steps):
    env, params = specrl_jax.make("LetterLTL0-v0")
    spec = automata.compile_spec(formula, env.propositions, alphabet=env.alphabet)
    task = TaskEnv(env, automata.stack([spec]))
    network = genz.GenZNetwork()
    net_params = network.init(jax.random.key(1), {"grid": jnp.zeros((7, 7, 1))})
    policy = genz.make_policy(network, env.alphabet, env.obs_kinds, replan_steps=replan_steps)
    return env, params, task, net_params, policy


def test_genz_timeout_gives_up_the_reach_proposition_then_the_episode():
    env, params, task, net_params, policy = _genz_setup("F a & F b & F c", replan_steps=1)
    obs, task_state = task.reset(jax.random.key(0), params, spec_index=0)
    carry = jax.jit(policy.init)(net_params, obs, task_state, jax.random.key(2))
    apply = jax.jit(policy.apply)
    chosen = []
    for i in range(4):  # the automaton never moves: from the second call on, each times out
        _, carry = apply(net_params, obs, task_state, carry, jax.random.key(3 + i))
        chosen.append(int(np.argmax(carry.reach)))
        assert bool(policy.aborted(carry)) == (i == 3)
    assert sorted(chosen[:3]) == [0, 1, 2], chosen  # a, b, c each tried once, then nothing is left
    # through the evaluator: an episode whose automaton never moves is given up before step 3,
    # as neither success nor violation; one that moves clears its marks and goes on
    t = evaluate(policy, (env, params), ["F a & F b & F c"], seeds=[1], episodes_per_seed=8,
                 policy_params=net_params).table
    assert t.aborted.any()
    assert not (t.aborted & (t.success | t.violation)).any()
    assert (t.steps[t.aborted] >= 3).all() and (t.steps[t.aborted] == 3).any()


def test_genz_timeout_in_an_accepting_self_loop_marks_nothing():
    env, params, task, net_params, policy = _genz_setup("G F a", replan_steps=1)
    obs, task_state = task.reset(jax.random.key(0), params, spec_index=0)
    carry = jax.jit(policy.init)(net_params, obs, task_state, jax.random.key(2))
    apply = jax.jit(policy.apply)
    on_a = task_state.replace(propositions=jnp.asarray(env.alphabet)[1 + 0])  # {a}: accepting loop
    assert bool(task_state.spec.accepting[task_state.q, 1]) and np.asarray(on_a.propositions)[0]
    for state, gives_up in ((on_a, False), (task_state, True)):
        _, after = apply(net_params, obs, state, carry._replace(steps=jnp.int32(1)), jax.random.key(3))
        assert bool(policy.aborted(after)) == gives_up  # 'a' is the only candidate
        assert int(after.steps) == 1  # the timer restarted


def test_sequence_encoder_reads_only_the_remaining_pairs():
    num_symbols, length = 4, 3
    rng = np.random.default_rng(0)
    reach, avoid = rng.random((2, length, num_symbols)) < 0.5
    obs = deepltl.SequenceObs(
        parts={"grid": jnp.zeros((7, 7, 3))}, reach=jnp.asarray(reach), avoid=jnp.asarray(avoid),
        epsilon=jnp.zeros(length, bool), start=jnp.int32(1), end=jnp.int32(2),
        epsilon_allowed=jnp.asarray(False),
    )
    encoder = deepltl.SequenceEncoder(num_symbols)
    params = encoder.init(jax.random.key(0), obs)
    base = encoder.apply(params, obs)
    outside = obs._replace(reach=obs.reach.at[0].set(~obs.reach[0]).at[2].set(~obs.reach[2]))
    np.testing.assert_allclose(encoder.apply(params, outside), base, atol=1e-6)
    inside = obs._replace(avoid=obs.avoid.at[1].set(~obs.avoid[1]))
    assert not np.allclose(encoder.apply(params, inside), base)
    # reversed reading: the current pair is read last, so the order of two pairs matters
    two = obs._replace(start=jnp.int32(0), end=jnp.int32(2))
    swapped = two._replace(reach=two.reach[jnp.array([1, 0, 2])], avoid=two.avoid[jnp.array([1, 0, 2])])
    assert not np.allclose(encoder.apply(params, two), encoder.apply(params, swapped))


def test_evaluate_runs_each_trained_seed_on_the_suite_protocol(monkeypatch):
    from specrl_jax.benchmark import experiment

    monkeypatch.setattr("specrl_jax.specs.suite", lambda name: ["F a", "!b U c"])
    world, params = make_letter_world(LetterConfig())
    method = genz.make_method(world, params)
    obs, _ = method.env.reset(jax.random.key(0), method.init_task_params())
    one = method.network.init(jax.random.key(0), jax.tree.map(lambda x: x[None], obs))
    two_seeds = jax.tree.map(lambda x: jnp.stack([x, x]), one)
    (suite,) = experiment.evaluate("genz", "LetterLTL0-v0", two_seeds, ["letter/finite/ind"], 3,
                                      log=lambda s: None)
    table = suite.result.table
    assert table.success.shape == (2, 2, 3) and suite.result.horizon == 75
    assert suite.result.seeds == (1, 2) and suite.method == "GenZ-LTL"
    assert np.all(table.steps <= 75) and not np.any(table.success & table.violation)
    # compiled from the parameters' shapes alone (as `specrl-jax run` does while it trains)
    shapes = experiment.param_shapes("genz", "LetterLTL0-v0", 2)
    assert jax.tree.map(lambda x: x.shape, shapes) == jax.tree.map(lambda x: x.shape, two_seeds)
    evaluate = experiment.prepare_evaluation_in_background(
        "genz", "LetterLTL0-v0", 2, ["letter/finite/ind"], 3, log=lambda s: None).result()
    (again,) = evaluate(jax.device_get(two_seeds))
    for a, b in zip(again.result.table, table, strict=True):
        np.testing.assert_array_equal(a, b)


def test_aborted_episodes_count_as_other_and_leave_mu_acc():
    from specrl_jax.eval.metrics import EpisodeTable, per_seed_metrics

    fields = ([0, 0, 0, 0], [0, 1, 0, 0], [75, 4, 3, 75], [6, 2, 1, 4], [0, 0, 1, 0])
    m = per_seed_metrics(EpisodeTable(*(np.asarray(x, bool if i in (0, 1, 4) else int)[None, None]
                                        for i, x in enumerate(fields))))
    assert m["eta_v"][0, 0] == 0.25 and m["eta_o"][0, 0] == 0.75
    assert m["mu_acc"][0, 0] == 5.0  # (6 + 4) / 2: the violating and the aborted episode are out


def test_committed_genz_parameters_give_the_same_network_with_the_library_convolution(monkeypatch):
    # the committed seed (trained through the task loop) under our matmul 2x2 convolution and
    # under flax's nn.Conv with the same parameters
    import flax.linen as nn

    from specrl_jax.baselines import encoders
    from specrl_jax.benchmark import experiment, store

    path = store.params_path("LetterLTL0-v0/genz")
    params = jax.tree.map(lambda x: x[0], experiment.load_params("genz", "LetterLTL0-v0", path, 1))
    images = {"grid": jax.random.choice(jax.random.key(3), jnp.array([0.0, 0.2, 0.5, 1.0]), (16, 7, 7, 1))}
    current = genz.GenZNetwork().apply(params, images)

    class LetterCNN(nn.Module):  # the same name, so the same parameter path `LetterCNN_0/Conv_i`
        @nn.compact
        def __call__(self, image):
            x = image.astype(jnp.float32)
            for width in (16, 32, 64):
                x = nn.relu(nn.Conv(width, (2, 2), padding="VALID")(x))
            return x.reshape(*x.shape[:-3], -1)

    monkeypatch.setattr(encoders, "LetterCNN", LetterCNN)
    library = genz.GenZNetwork().apply(params, images)
    assert float(jnp.std(library.value)) > 1e-3  # trained weights, not a zero template
    for a, b in ((current.pi.logits, library.pi.logits), (current.value, library.value),
                 (current.cost_value, library.cost_value), (current.multiplier, library.multiplier)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)


def test_training_rewards_see_the_world_reward_as_their_originals_do():
    """A step that neither completes nor violates the task but ends the world's episode with
    its reward -1 (a Zone wall crossing): LTL2Action, DeepLTL and RAD-Embeddings train on -1
    (their wrappers keep the env reward), GenZ-LTL on cost 1, GCRL-LTL's goal reward stays 0."""
    from specrl_jax.baselines import ltl2action, rad
    from specrl_jax.baselines.gcrl import make_method as gcrl_method

    world, params = specrl_jax.make("LetterLTL0-v0")
    false = jnp.zeros((), bool)
    wall = {"success": false, "violation": false, "progress": false, "env_terminated": ~false,
            "env_reward": jnp.float32(-1.0)}
    for module in (ltl2action, deepltl, rad):
        reward, cost, _ = module.make_method(world, params).env.signals(wall)
        assert (float(reward), float(cost)) == (-1.0, 0.0), module.__name__
    reward, cost, _ = genz.make_method(world, params).env.signals(wall)
    assert (float(reward), float(cost)) == (0.0, 1.0)
    reward, _, _ = gcrl_method(world, params).env.signals(wall)
    assert float(reward) == 0.0
    done = dict(wall, success=~false)  # completing the task: +1 whatever the world gives
    assert float(deepltl.make_method(world, params).env.signals(done)[0]) == 1.0


def test_deepltl_stay_steps_lengthen_the_reach_stay_tasks_it_trains_on():
    from specrl_jax.baselines.spec import get_method

    world, params = specrl_jax.make("PointLTL0-v0")
    default = deepltl.make_method(world, params).env.task.source.sampler.curriculum
    longer = deepltl.make_method(world, params, stay_steps=600).env.task.source.sampler.curriculum
    assert default.name == "deepltl/zone" and longer.name == "deepltl/zone+stay600"
    get_method("deepltl").check_options({"stay_steps": 600})
    with pytest.raises(ValueError, match="accepted: stay_steps, twins_apart"):
        get_method("deepltl").check_options({"stay": 600})
    with pytest.raises(ValueError, match="no reach-stay tasks"):
        deepltl.make_method(*specrl_jax.make("LetterLTL0-v0"), stay_steps=100)
    with pytest.raises(ValueError, match="must fit in the world's training episode of 1000"):
        deepltl.make_method(world, params, stay_steps=999)


def test_deepltl_twins_apart_reads_the_worlds_same_object_propositions():
    world, params = specrl_jax.make("PandaLTLReach1Joints-v0")
    assert world.same_object[0] == ("arm_blue", "grippers_blue") and len(world.same_object) == 4
    assert specrl_jax.make("PandaLTLReach0Joints-v0")[0].same_object == ()
    sampler = deepltl.make_method(world, params, twins_apart=True).env.task.source.sampler
    p = world.propositions
    assert sampler.twins.sum() == 8 and sampler.twins[p.index("arm_green"), p.index("grippers_green")]
    assert deepltl.make_method(world, params).env.task.source.sampler.twins is None
    with pytest.raises(ValueError, match="declares no propositions that name one object"):
        deepltl.make_method(*specrl_jax.make("PointLTL0-v0"), twins_apart=True)
    with pytest.raises(TypeError, match="twins_apart must be True or False, got 'false'"):
        deepltl.make_method(world, params, twins_apart="false")
