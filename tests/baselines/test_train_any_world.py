"""Training goes through the task loop on every single-agent world: building every registered ID,
one update on each robot, training and evaluation agreeing on an episode, clear errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import specrl_jax
from specrl_jax import automata, families
from specrl_jax.baselines import deepltl, gcrl, genz, ltl2action, rad
from specrl_jax.baselines.ppo import PPOConfig, make_train
from specrl_jax.baselines.rad import pretrain as rad_pretrain
from specrl_jax.baselines.spec import get_method
from specrl_jax.baselines.train_env import TaskTrainEnv
from specrl_jax.benchmark import experiment
from specrl_jax.eval.evaluate import run_episode
from specrl_jax.tasks import TaskEnv, as_stateful

SINGLE_AGENT = [e for e in specrl_jax.list_envs() if families.family_of_id(e).trainable]


def test_every_single_agent_id_builds_a_training_env_for_each_method():
    for env_id in SINGLE_AGENT:
        world, params = specrl_jax.make(env_id)
        family = experiment.family(env_id)
        for module in (genz, deepltl):
            method = module.make_method(world, params, family)
            assert method.env.task.env is world
            config = module.ppo_config(family)
            assert config.gamma == {"letter": 0.94, "zone": 0.998, "arm": 0.99}[family]
        assert int(params.max_steps) == {"letter": 75, "zone": 1000, "arm": 200}[family]


# Zone worlds share their code and networks whatever the robot: each method meets a Zone robot
# once (Car with GenZ-LTL, Ant with DeepLTL); Point goes through Brax PPO in tests/test_brax.py
@pytest.mark.parametrize("env_id, module", [
    ("LetterLTL0-v0", genz), ("LetterLTL0-v0", deepltl), ("CarLTL0-v0", genz),
    ("AntLTL0-v0", deepltl), ("PandaLTLReach0Joints-v0", genz), ("PandaLTLReach1Joints-v0", deepltl),
], ids=["letter-genz", "letter-deepltl", "car-genz", "ant-deepltl", "arm0-genz", "arm1-deepltl"])
def test_one_update_on_each_robot(env_id, module):
    """One PPO update through the task loop: finite losses, the world's own batch."""
    # the arm without its table contacts: MJX's mesh collision is most of the tracing time
    world, params = specrl_jax.make(env_id, **({"table_contacts": False} if "Panda" in env_id else {}))
    method = module.make_method(world, params, experiment.family(env_id))
    cfg = module.ppo_config(experiment.family(env_id), num_envs=2, num_steps=4, num_minibatches=1,
                            update_epochs=1, total_timesteps=8)
    trainer = make_train(cfg, method)
    if not env_id.startswith("Letter"):  # MJX worlds compile for minutes on XLA:CPU: trace only
        runner = jax.eval_shape(trainer.init, jax.random.key(0))
        out = jax.eval_shape(trainer.update, runner)[1]
        assert out["policy_loss"].shape == () and runner.update.shape == ()
        return
    runner = jax.jit(trainer.init)(jax.random.key(0))
    runner, metrics = jax.jit(trainer.update)(runner)
    assert int(runner.update) == 1
    assert all(np.isfinite(np.asarray(v)).all() for v in metrics.values())


# the other three methods meet each kind of world once, traced only (their Letter updates run in
# their own tests); small formula / task banks keep the host-side builds to seconds
@pytest.mark.parametrize("env_id, module, options", [
    ("CarLTL0-v0", ltl2action, {"num_formulas": 8}),
    ("PandaLTLReach1Joints-v0", ltl2action, {"num_formulas": 8}),
    ("PointLTL0-v0", gcrl, {}),
    ("PandaLTLReach0Joints-v0", gcrl, {}),
    ("PandaLTLReach0Joints-v0", rad, {"bank_size": 16}),
], ids=["car-ltl2action", "arm1-ltl2action", "point-gcrl", "arm0-gcrl", "arm0-rad"])
def test_the_other_methods_trace_an_update_on_the_mjx_worlds(env_id, module, options):
    world, params = specrl_jax.make(env_id, **({"table_contacts": False} if "Panda" in env_id else {}))
    family = experiment.family(env_id)
    method = module.make_method(world, params, family, **options)
    cfg = module.ppo_config(family, num_envs=2, num_steps=4, num_minibatches=1, update_epochs=1,
                            total_timesteps=8)
    trainer = make_train(cfg, method)
    runner = jax.eval_shape(trainer.init, jax.random.key(0))
    metrics = jax.eval_shape(trainer.update, runner)[1]
    assert metrics["policy_loss"].shape == () and metrics["value_loss"].shape == ()


def test_rad_on_the_grippers_arm_alphabet_names_the_missing_encoder(monkeypatch, tmp_path):
    """The grippers-only arm reads the shipped Zone encoder (same alphabet); grippers+arm's 256
    assignments read the arm's own overlap encoder, and where it is missing the error says how to
    make it instead of failing inside the network."""
    monkeypatch.setattr(rad_pretrain, "encoder_path", lambda name: tmp_path / f"rad_{name}.msgpack")
    world, params = specrl_jax.make("PandaLTLReach1Joints-v0", table_contacts=False)
    with pytest.raises(ValueError, match=r"rad_arm_overlap.msgpack; make one with `specrl-jax "
                                         r"pretrain --method rad --env ID` with ID a world of the "
                                         r"arm family .*PandaLTLReach1Joints-v0"):
        rad.make_method(world, params, "arm", bank_size=16)


def test_training_and_evaluation_agree_on_an_episode():
    """The trainer's env and the evaluator run the same task loop: same key, same actions, same
    flags and step counts."""
    world, params = specrl_jax.make("LetterLTL0-v0")
    specs = automata.compile_suite(("!a U b", "F (c & F d)", "G !e & F f"), world.propositions, world.alphabet)
    task = TaskEnv(world, specs)
    actions = jax.random.randint(jax.random.key(5), (75,), 0, 4)
    policy = as_stateful(lambda p, obs, state, key: actions[state.time])
    train_env = TaskTrainEnv(task, params, signals=lambda info: (0.0, 0.0, jnp.zeros((), bool)))
    episode = jax.jit(lambda k, i: run_episode(policy, task, params, 75, None, k, i))
    step = jax.jit(train_env.step)
    for index in range(3):
        key = jax.random.key(index)
        final, _, _, _ = episode(key, index)
        _, state = task.reset(jax.random.split(key, 3)[0], params, index)
        for t in range(75):
            _, state, result = step(jax.random.key(100 + t), state, actions[t], None)
            if bool(result.terminated | result.truncated):
                break
        assert bool(result.stats["_success"]) == bool(final.success)
        assert bool(result.stats["violations"]) == bool(final.violation)
        assert t + 1 == int(final.time)


def test_clear_errors_for_unknown_methods_and_envs():
    with pytest.raises(ValueError, match="unknown method 'ppo'; accepted: genz, deepltl"):
        get_method("ppo")
    with pytest.raises(ValueError, match="cannot train on env 'Nope-v0'; single-agent IDs: Ant"):
        experiment.family("Nope-v0")


def test_image_worlds_learn_their_seeds_in_turn_on_an_accelerator():
    assert experiment.observes_images("PointLTL0Vision-v0", {"image_size": 32})
    assert not experiment.observes_images("PointLTL0-v0")
    assert not experiment.observes_images("LetterLTL0-v0")
    assert experiment.default_overrides("gpu", None, "zone", "genz", images=True)["learn_seeds_in_turn"]
    for device, images in (("cpu", True), ("gpu", False)):
        assert "learn_seeds_in_turn" not in experiment.default_overrides(device, None, "zone", "genz", images)


def test_every_method_takes_the_image_cnn_dtype_as_an_option(monkeypatch):
    """`--method-option image_dtype=bfloat16` reaches every method's image CNN: the network each
    method trains (GCRL-LTL's after its primitives are trained, too) runs its convolutions on
    bfloat16 operands; anything but float32 / bfloat16 is refused with the accepted values."""
    world, params = specrl_jax.make("PointLTL0Vision-v0", image_size=64)
    key = jax.random.key(0)
    monkeypatch.setattr(gcrl.primitives_lib, "cached_primitives",
                        lambda world, params, key, config, primitives, log: primitives)
    for name in ("genz", "deepltl", "ltl2action", "gcrl", "rad"):
        spec = get_method(name)
        assert "image_dtype" in spec.options, name
        with pytest.raises(ValueError, match="image_dtype='float16'; choose one of float32, bfloat16"):
            spec.make_method(world, params, "zone", image_dtype="float16")
        method = spec.make_method(world, params, "zone", image_dtype="bfloat16")
        if name == "gcrl":
            method = gcrl.prepare_training(method, key, PPOConfig(total_timesteps=1_500),
                                            log=lambda _: None)
        obs, _ = method.env.reset(key, method.init_task_params())
        variables = method.network.init(key, obs)
        text = jax.jit(method.network.apply).trace(variables, obs).lower(
            lowering_platforms=("cuda",)).as_text()
        convolutions = [line for line in text.splitlines() if "stablehlo.convolution" in line]
        assert len(convolutions) == 5, (name, len(convolutions))  # the image CNN's layers
        assert all("xbf16>" in line.split("->")[-1] for line in convolutions), name
