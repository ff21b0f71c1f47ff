"""The shared PPO trainer: GAE and the losses against hand/numpy computations, resume, sharding."""

import dataclasses
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from specrl_jax.baselines import runs
from specrl_jax.baselines.ppo import PPOConfig, make_train
from specrl_jax.baselines.ppo.losses import (
    Batch,
    LossConfig,
    compute_gae,
    compute_reachability_cost,
    ppo_loss,
    rco_loss,
)
from specrl_jax.baselines.ppo.networks import Categorical, DiagGaussian, PolicyOutput
from specrl_jax.benchmark import experiment

sys.path.insert(0, str(Path(__file__).parent))
from chain import ChainMethod

TINY = PPOConfig(num_envs=4, num_steps=8, total_timesteps=4 * 8 * 4, update_epochs=2, num_minibatches=2)
# the KL stop fires at different epochs per seed and update (1-6 of 6); 5 updates
KL_FIRES = PPOConfig(num_envs=4, num_steps=8, total_timesteps=4 * 8 * 5, update_epochs=6, num_minibatches=2,
                     loss="rco", target_kl=1e-5, lr=0.03)


def test_gae_matches_hand_computation():
    gamma, lam = 0.9, 0.8
    reward = jnp.array([[1.0], [0.0], [2.0]])
    value = jnp.array([[0.5], [1.0], [1.5]])
    done = jnp.array([[False], [True], [False]])
    last_value = jnp.array([3.0])
    adv, target = compute_gae(reward, value, done, last_value, gamma, lam)
    d2 = 2.0 + 0.9 * 3.0 - 1.5  # bootstraps from last_value
    d1 = 0.0 - 1.0  # episode ends at step 1: no bootstrap
    d0 = 1.0 + 0.9 * 1.0 - 0.5
    a2, a1 = d2, d1
    a0 = d0 + gamma * lam * a1
    np.testing.assert_allclose(adv[:, 0], [a0, a1, a2], rtol=1e-6)
    np.testing.assert_allclose(target[:, 0], [a0 + 0.5, a1 + 1.0, a2 + 1.5], rtol=1e-6)


def test_reachability_cost_matches_hand_computation():
    gamma, lam = 0.9, 0.5
    cost = jnp.array([[-1.0], [1.0], [-1.0]])
    cost_value = jnp.array([[0.2], [0.4], [-0.5]])
    done = jnp.array([[False], [True], [False]])
    last = jnp.array([0.3])
    adv, target = compute_reachability_cost(cost, cost_value, done, last, gamma, lam)
    d2 = 0.1 * -1 + 0.9 * max(-1, 0.3) - (-0.5)
    d1 = 0.1 * 1 + 0.0 - 0.4
    d0 = 0.1 * -1 + 0.9 * max(-1, 0.4) - 0.2
    np.testing.assert_allclose(adv[:, 0], [d0 + gamma * lam * d1, d1, d2], rtol=1e-6, atol=1e-7)
    # C_2 = max(-1, 0) = 0 (rollout end), C_1 = 1 (violation, segment ends), C_0 = max(-1, 1) = 1
    np.testing.assert_allclose(target[:, 0], [1.0, 1.0, 0.0])


def _fixed_batch(n=6, actions=3, seed=0):
    rng = np.random.default_rng(seed)
    f = lambda *s: rng.normal(size=s).astype(np.float32)
    batch = Batch(
        obs=None, action=rng.integers(0, actions, n).astype(np.int32), log_prob=-np.abs(f(n)) - 0.5,
        value=f(n), cost_value=f(n), advantage=f(n), target=f(n), cost_advantage=f(n), cost_target=f(n),
    )
    logits = f(n, actions)
    out = PolicyOutput(Categorical(jnp.asarray(logits)), jnp.asarray(f(n)), jnp.asarray(f(n)),
                       jnp.asarray(np.abs(f(n)) * 3))
    return batch, out, logits


def _np_parts(batch, out, logits, cfg):
    logp_all = logits - np.log(np.exp(logits).sum(-1, keepdims=True))
    logp = logp_all[np.arange(len(batch.action)), batch.action]
    ratio = np.exp(logp - batch.log_prob)
    adv = batch.advantage
    if cfg.normalize_advantages:
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    surr = np.minimum(ratio * adv, np.clip(ratio, 1 - cfg.clip_eps, 1 + cfg.clip_eps) * adv)
    entropy = -(np.exp(logp_all) * logp_all).sum(-1).mean()

    def vloss(v, old, tgt):
        v = np.asarray(v)
        clipped = old + np.clip(v - old, -cfg.clip_eps, cfg.clip_eps)
        return np.maximum((v - tgt) ** 2, (clipped - tgt) ** 2).mean()

    return ratio, surr, entropy, vloss


@pytest.mark.parametrize("normalize", [False, True])
def test_ppo_loss_matches_numpy(normalize):
    cfg = LossConfig(ent_coef=0.01, vf_coef=0.5, normalize_advantages=normalize)
    batch, out, logits = _fixed_batch()
    _ratio, surr, entropy, vloss = _np_parts(batch, out, logits, cfg)
    expected = -surr.mean() - 0.01 * entropy + 0.5 * vloss(out.value, batch.value, batch.target)
    loss, _ = ppo_loss(out, batch, cfg)
    np.testing.assert_allclose(loss, expected, rtol=1e-5)


def test_rco_loss_matches_numpy():
    cfg = LossConfig(ent_coef=0.01, vf_coef=1.0, gamma=0.94)
    batch, out, logits = _fixed_batch(seed=1)
    ratio, surr, entropy, vloss = _np_parts(batch, out, logits, cfg)
    lam = np.clip(np.asarray(out.multiplier), 0.01, 5.0)
    g = ratio * batch.cost_advantage + 0.06 * batch.cost_target + 0.05
    expected = (
        np.mean(-surr + lam * g)
        + vloss(out.value, batch.value, batch.target)
        + vloss(out.cost_value, batch.cost_value, batch.cost_target)
        - np.mean(lam * g)
        - 0.01 * entropy
    )
    loss, _ = rco_loss(out, batch, cfg)
    np.testing.assert_allclose(loss, expected, rtol=1e-5)
    # the multiplier is trained by its own term only (ascent on the constraint): d loss / d lam_i = -g_i / N
    grad = jax.grad(lambda m: rco_loss(out._replace(multiplier=m), batch, cfg)[0])(out.multiplier)
    inside = (np.asarray(out.multiplier) > 0.01) & (np.asarray(out.multiplier) < 5.0)
    np.testing.assert_allclose(np.asarray(grad)[inside], (-g / len(g))[inside], rtol=1e-5)


def test_gaussian_log_prob_and_entropy_match_scipy():
    from scipy.stats import norm

    mean, std = np.array([[0.1, -0.3]]), np.array([[0.5, 1.2]])
    action = np.array([[0.4, 0.0]])
    dist = DiagGaussian(jnp.asarray(mean), jnp.asarray(std))
    np.testing.assert_allclose(dist.log_prob(action), norm.logpdf(action, mean, std).sum(-1), rtol=1e-5)
    np.testing.assert_allclose(dist.entropy(), norm.entropy(mean, std).sum(-1), rtol=1e-5)


def test_the_entropy_bonus_is_per_action_dimension_as_torch_ac_averages_it():
    """torch-ac's baselines reward `dist.entropy().mean()`: a Normal's per-dimension entropies
    (DeepLTL's epsilon mixture scales them by 1 - p where the jump is allowed) averaged over the
    batch and the action dimensions; SB3 sums the dimensions (`entropy_per_action_dim=False`)."""
    from scipy.stats import norm

    from specrl_jax.baselines.ppo.networks import EpsilonGaussian

    rng = np.random.default_rng(0)
    mean, std = rng.normal(size=(6, 3)), rng.uniform(0.2, 1.3, (6, 3))
    p_eps, allowed = rng.uniform(0.1, 0.9, 6), np.array([True, False] * 3)
    per_dim = norm.entropy(mean, std)  # [6, 3], torch's Normal(mean, std).entropy()
    scaled = per_dim * np.where(allowed, 1 - p_eps, 1.0)[:, None]
    batch, out, _ = _fixed_batch()
    zero = LossConfig(ent_coef=1.0, vf_coef=0.0)
    for pi, torch_ac in ((DiagGaussian(jnp.asarray(mean), jnp.asarray(std)), per_dim.mean()),
                         (EpsilonGaussian(DiagGaussian(jnp.asarray(mean), jnp.asarray(std)),
                                          jnp.asarray(p_eps), jnp.asarray(allowed)),
                          scaled.mean())):
        given = out._replace(pi=pi)
        moves = batch._replace(action=jnp.zeros((6, 3 + isinstance(pi, EpsilonGaussian))))
        for loss_fn in (ppo_loss, rco_loss):
            _, metrics = loss_fn(given, moves, zero)
            np.testing.assert_allclose(metrics["entropy"], torch_ac, rtol=1e-5)
        _, joint = ppo_loss(given, moves, zero._replace(entropy_per_action_dim=False))
        np.testing.assert_allclose(joint["entropy"], 3 * torch_ac, rtol=1e-5)


def test_kl_early_stop_limits_epochs():
    loose = PPOConfig(**{**TINY.__dict__, "update_epochs": 6, "loss": "rco", "target_kl": 1e9})
    tight = PPOConfig(**{**TINY.__dict__, "update_epochs": 6, "loss": "rco", "target_kl": -1.0})
    _, m_loose = jax.jit(make_train(loose, ChainMethod()))(jax.random.key(0))
    _, m_tight = jax.jit(make_train(tight, ChainMethod()))(jax.random.key(0))
    assert np.all(m_loose["epochs"] == 6)
    assert np.all(m_tight["epochs"] == 1)


def test_the_flat_optimizer_matches_clipping_and_adam_per_leaf():
    import optax

    cfg = PPOConfig(**{**TINY.__dict__, "update_epochs": 2, "loss": "rco", "max_grad_norm": 1e-3})
    flat, per_leaf = make_train(cfg, ChainMethod()), make_train(cfg, ChainMethod())
    per_leaf.optimizer = optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm),
                                     optax.adam(cfg.lr, eps=cfg.adam_eps))
    a, _ = jax.jit(flat)(jax.random.key(3))
    b, _ = jax.jit(per_leaf)(jax.random.key(3))
    start = jax.jit(flat.init)(jax.random.key(3)).params
    assert a.opt_state[1][0].mu.ndim == 1 and isinstance(b.opt_state[1][0].mu, dict)
    assert not np.allclose(jax.tree.leaves(a.params)[0], jax.tree.leaves(start)[0])
    for x, y in zip(jax.tree.leaves(a.params), jax.tree.leaves(b.params), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6)


def test_a_chunk_traces_the_update_once():
    """The skipped updates' zeros take their shapes from the one trace of the update (a second
    trace of an MJX world's step took seconds to a minute on a CPU)."""
    trainer = make_train(TINY, ChainMethod())
    update, traces = trainer.update, []
    trainer.update = lambda runner: (traces.append(1), update(runner))[1]
    runner = jax.eval_shape(trainer.init, jax.random.key(0))
    jax.jit(trainer.updates, static_argnums=1).trace(runner, 3, jnp.int32(1))
    assert len(traces) == 1


def test_partly_active_chunks_continue_like_a_full_chunk():
    # one compiled 3-update chunk: 2 active then 1 active must equal 3 active
    trainer = make_train(TINY, ChainMethod())
    updates = jax.jit(trainer.updates, static_argnums=1)
    runner = jax.jit(trainer.init)(jax.random.key(5))
    full, m_full = updates(runner, 3, jnp.int32(3))
    part, m_part = updates(runner, 3, jnp.int32(2))
    assert int(part.update) == 2 and m_part["epochs"][2] == 0  # the idle update computed nothing
    rest, m_rest = updates(part, 3, jnp.int32(1))
    assert int(rest.update) == int(full.update) == 3
    for a, b in zip(jax.tree.leaves(full.params), jax.tree.leaves(rest.params)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(jax.random.key_data(full.key), jax.random.key_data(rest.key))
    rewards = np.concatenate([m_part["reward"][:2], m_rest["reward"][:1]])
    np.testing.assert_array_equal(rewards, m_full["reward"])


def test_two_seeds_with_an_idle_tail_and_kl_stops_run_only_the_active_epochs(tmp_path):
    # chunks of 3 over 5 updates: the second chunk runs 2 updates and idles the third
    trainer = make_train(KL_FIRES, ChainMethod())
    heard = []  # on_compiled runs once, after the step compiled and before any update ran
    runner = runs.train_in_run_dir(
        trainer, jax.random.key(11), tmp_path, chunk_updates=3, num_seeds=2, log=heard.append,
        on_compiled=lambda: heard.append(f"on_compiled, rows {len(runs.read_metrics(tmp_path))}"))
    assert heard.count("on_compiled, rows 0") == 1 and not any(
        h.startswith("on_compiled, rows") for h in heard if h != "on_compiled, rows 0")
    at = heard.index("on_compiled, rows 0")
    compiled_step = next(i for i, h in enumerate(heard) if h.startswith("compiled the training step"))
    assert compiled_step < at and heard[at + 1].startswith("update 3/5")
    # a fresh run compiles the training step while the initial state compiles
    init_done = next(i for i, h in enumerate(heard) if h.startswith("compiled the initial state"))
    assert heard.index("compiling the training step ...") < init_done
    rows = runs.read_metrics(tmp_path)
    assert [r["update"] for r in rows] == [1, 2, 3, 4, 5] and list(runner.update) == [5, 5]
    epochs = np.array([r["epochs"] for r in rows])  # mean over the 2 seeds
    assert epochs.min() < KL_FIRES.update_epochs  # the KL stop fired
    adam_steps = np.asarray(runner.opt_state[1][0].count)  # one per minibatch step, per seed
    assert adam_steps.sum() == KL_FIRES.num_minibatches * 2 * epochs.sum()  # idle updates took none


def test_a_run_whose_lowering_is_not_thread_safe_compiles_one_program_at_a_time(tmp_path):
    heard = []
    runs.train_in_run_dir(make_train(KL_FIRES, ChainMethod()), jax.random.key(11), tmp_path,
                          chunk_updates=3, log=heard.append, compile_step_early=False)
    compiles = [h.split(" in ")[0] for h in heard if h.startswith("compil")]
    assert compiles == ["compiling the initial state (env reset, network init) ...",
                        "compiled the initial state (env reset, network init)",
                        "compiling the training step ...", "compiled the training step"]


def test_seeds_learning_in_turn_match_seeds_learning_side_by_side(tmp_path):
    # chunks of 3 over 5 updates (an idle tail); the KL stop fires at other epochs per seed
    in_turn = make_train(dataclasses.replace(KL_FIRES, learn_seeds_in_turn=True), ChainMethod())
    side_by_side = make_train(KL_FIRES, ChainMethod())
    options = {"chunk_updates": 3, "num_seeds": 2, "log": lambda s: None}
    a = runs.train_in_run_dir(in_turn, jax.random.key(11), tmp_path / "turn", **options)
    b = runs.train_in_run_dir(side_by_side, jax.random.key(11), tmp_path / "vmap", **options)
    rows = [runs.read_metrics(tmp_path / d) for d in ("turn", "vmap")]
    assert [r["epochs"] for r in rows[0]] == [r["epochs"] for r in rows[1]]
    assert len({r["epochs"] for r in rows[0]}) > 1 and list(a.update) == [5, 5]
    for x, y in zip(jax.tree.leaves(a.params), jax.tree.leaves(b.params), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(jax.random.key_data(a.key), jax.random.key_data(b.key))


def test_one_seed_unbatched_matches_the_vmapped_trainer(tmp_path):
    # `runs` trains one seed without vmap; the KL stop's while-loop must give the same run
    trainer = make_train(KL_FIRES, ChainMethod())
    key = jax.random.key(11)
    runner = runs.train_in_run_dir(trainer, key, tmp_path, chunk_updates=3, log=lambda s: None)
    init = jax.tree.map(lambda x: x[None], jax.jit(trainer.init)(jax.random.split(key, 1)[0]))
    vmapped = jax.jit(jax.vmap(trainer.updates, in_axes=(0, None)), static_argnums=1)
    batched, metrics = vmapped(init, KL_FIRES.num_updates)
    epochs = [r["epochs"] for r in runs.read_metrics(tmp_path)]
    assert epochs == np.asarray(metrics["epochs"][0], float).tolist() and min(epochs) < 6
    for a, b in zip(jax.tree.leaves(batched.params), jax.tree.leaves(runner.params)):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(jax.random.key_data(batched.key), jax.random.key_data(runner.key))


def test_letter_cnn_matches_the_library_convolution():
    import flax.linen as nn

    from specrl_jax.baselines.ppo.networks import LetterCNN

    image = jax.random.uniform(jax.random.key(0), (3, 7, 7, 2))
    cnn = LetterCNN()
    params = cnn.init(jax.random.key(1), image)["params"]

    @jax.jit
    def reference(p, x):
        for i, width in enumerate(cnn.channels):
            x = nn.relu(nn.Conv(width, (2, 2), padding="VALID").apply({"params": p[f"Conv_{i}"]}, x))
        return x.reshape(x.shape[0], -1)

    out = jax.jit(cnn.apply)({"params": params}, image)
    assert out.shape == (3, 4 * 4 * 64)
    np.testing.assert_allclose(out, reference(params, image), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("conv", ["patch", "library_forward", "auto"])
def test_image_cnn_matches_the_library_convolution_per_seed_in_value_and_gradient(conv):
    import flax.linen as nn

    from specrl_jax.baselines.encoders import ImageCNN

    images = jax.random.randint(jax.random.key(0), (2, 3, 64, 64, 3), 0, 256).astype(jnp.uint8)
    cnn = ImageCNN(conv=conv)
    params = jax.vmap(lambda k: cnn.init(k, images[0])["params"])(jax.random.split(jax.random.key(1), 2))

    def reference(p, x):
        x = x.astype(jnp.float32) / 255.0
        for i, width in enumerate(cnn.channels):
            conv = nn.Conv(width, (5, 5), strides=(2, 2), padding=((1, 1), (1, 1)))
            x = nn.relu(conv.apply({"params": p[f"Conv_{i}"]}, x))
        return x.reshape(x.shape[0], -1)

    def loss(apply):
        return lambda p, x: jnp.sum(jnp.sin(apply(p, x)))

    ours = jax.jit(jax.vmap(jax.value_and_grad(loss(lambda p, x: cnn.apply({"params": p}, x)))))
    library = jax.jit(jax.vmap(jax.value_and_grad(loss(reference))))
    (value, grad), (ref_value, ref_grad) = ours(params, images), library(params, images)
    assert cnn.apply({"params": jax.tree.map(lambda x: x[0], params)}, images[0]).shape == (3, 32)
    with pytest.raises(ValueError, match="needs an input of at least 3 x 3; got 1 x 1"):
        cnn.init(jax.random.key(0), images[0, :, :32, :32])  # 32 -> 15 -> 7 -> 3 -> 1 -> none
    np.testing.assert_allclose(value, ref_value, rtol=1e-4)
    for a, b in zip(jax.tree.leaves(grad), jax.tree.leaves(ref_grad)):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-4 * float(jnp.max(jnp.abs(b))))


def test_image_cnn_auto_takes_the_library_gradient_for_one_set_of_parameters_off_the_cpu():
    """`ImageCNN(conv="auto")` lowered for a GPU: the library convolution forward and backward
    for one set of parameters (seeds learning in turn: `lax.map`), the patch matmul for the
    gradient of a batch of them (`vmap`); on the CPU the patch matmul throughout."""
    from specrl_jax.baselines.encoders import ImageCNN

    cnn = ImageCNN()
    images = jnp.zeros((2, 64, 64, 3), jnp.uint8)
    params = cnn.init(jax.random.key(0), images)
    grad = jax.grad(lambda p, x: jnp.sum(jnp.sin(cnn.apply(p, x))))
    seeds = jax.tree.map(lambda a: jnp.stack([a, a]), (params, images))
    programs = {"one": (grad, (params, images)),
                "in_turn": (lambda p, x: jax.lax.map(lambda a: grad(*a), (p, x)), seeds),
                "side_by_side": (jax.vmap(grad), seeds)}

    def ops(name, platform):
        fn, args = programs[name]
        text = jax.jit(fn).trace(*args).lower(lowering_platforms=(platform,)).as_text()
        return text.count("stablehlo.convolution"), text.count("stablehlo.dot_general")

    layers = len(cnn.channels)
    for name in programs:
        assert ops(name, "cpu")[0] == 0
    for name in ("one", "in_turn"):
        convolutions, matmuls = ops(name, "cuda")
        assert convolutions > 2 * layers and matmuls == 0
    # the forward pass a convolution per layer, the gradient the patch matmuls
    assert ops("side_by_side", "cuda") == (layers, 2 * layers - 1)


def test_image_cnn_in_bfloat16_keeps_float32_parameters_and_stays_near_float32():
    """`compute_dtype="bfloat16"`: the convolutions run on bfloat16 operands, in the lowered GPU
    program too (the gradient's included); parameters, output and gradients stay float32 and
    within bfloat16's precision of the float32 network's."""
    from specrl_jax.baselines.encoders import ImageCNN

    images = jax.random.randint(jax.random.key(0), (4, 64, 64, 3), 0, 256).astype(jnp.uint8)
    full, half = ImageCNN(), ImageCNN(compute_dtype="bfloat16")
    params = full.init(jax.random.key(1), images)
    assert jax.tree.structure(half.init(jax.random.key(1), images)) == jax.tree.structure(params)
    loss = {name: jax.jit(jax.value_and_grad(lambda p, x, m=m: jnp.sum(jnp.sin(m.apply(p, x)))))
            for name, m in (("full", full), ("half", half))}
    (_, g32), (_, g16) = loss["full"](params, images), loss["half"](params, images)
    out = half.apply(params, images)
    assert out.dtype == jnp.float32 and out.shape == (4, 32)
    np.testing.assert_allclose(out, full.apply(params, images), rtol=0.05, atol=0.02)
    for a, b in zip(jax.tree.leaves(g16), jax.tree.leaves(g32)):
        assert a.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(a)))
        assert float(jnp.linalg.norm(a - b)) < 0.05 * float(jnp.linalg.norm(b))
    text = jax.jit(jax.grad(lambda p, x: jnp.sum(half.apply(p, x)))).trace(params, images).lower(
        lowering_platforms=("cuda",)).as_text()
    convolutions = [line for line in text.splitlines() if "stablehlo.convolution" in line]
    assert len(convolutions) > 2 * len(half.channels)
    assert all("bf16" in line and "f32" not in line.split("->")[-1] for line in convolutions)
    with pytest.raises(ValueError, match="compute_dtype='float16'; choose one of float32, bfloat16"):
        ImageCNN(compute_dtype="float16").init(jax.random.key(0), images)


def test_resume_gives_identical_continuation(tmp_path, monkeypatch):
    clock = iter(range(1000))  # every chunk takes 1 s: a resumed run's clock must read as a straight one's
    monkeypatch.setattr(runs, "time", SimpleNamespace(perf_counter=lambda: float(next(clock))))
    trainer = make_train(TINY, ChainMethod())
    key = jax.random.key(3)
    options = {"chunk_updates": 2, "num_seeds": 2, "log": lambda s: None}
    straight = runs.train_in_run_dir(trainer, key, tmp_path / "a", **options)
    runs.train_in_run_dir(trainer, key, tmp_path / "b", max_updates=2, **options)
    resumed = runs.train_in_run_dir(trainer, key, tmp_path / "b", **options)
    assert int(resumed.update[0]) == int(straight.update[0]) == TINY.num_updates
    for a, b in zip(jax.tree.leaves(straight.params), jax.tree.leaves(resumed.params)):
        np.testing.assert_array_equal(a, b)
    rows_a, rows_b = runs.read_metrics(tmp_path / "a"), runs.read_metrics(tmp_path / "b")
    assert [r["update"] for r in rows_b] == [1, 2, 3, 4]
    assert [r["reward"] for r in rows_a] == [r["reward"] for r in rows_b]
    assert [r["wall_s"] for r in rows_a] == [r["wall_s"] for r in rows_b] == [1.0, 1.0, 2.0, 2.0]
    assert json.loads((tmp_path / "a" / "config.json").read_text())["ppo"]["num_envs"] == 4


def test_checkpoints_store_booleans_as_bits_and_read_unpacked_ones_too(tmp_path):
    from flax import serialization

    _, _, method, config = experiment.build("deepltl", "LetterLTL0-v0",
                                            {"num_envs": 4, "num_steps": 8}, None, jax.random.key(0))
    runner = jax.jit(make_train(config, method).init)(jax.random.key(3))
    flags = [x for x in jax.tree.leaves(runner) if x.dtype == bool]
    assert flags and sum(x.size for x in flags) >= 8  # the runner has boolean state to pack
    runs.save_checkpoint(tmp_path / "packed.msgpack", runner)
    stored = serialization.msgpack_restore((tmp_path / "packed.msgpack").read_bytes())
    assert not any(np.asarray(x).dtype == bool for x in jax.tree.leaves(stored))
    plain = jax.device_get(runner.replace(key=jax.random.key_data(runner.key)))
    (tmp_path / "plain.msgpack").write_bytes(serialization.to_bytes(plain))  # the earlier format
    for name in ("packed", "plain"):
        loaded = runs.load_checkpoint(tmp_path / f"{name}.msgpack", runner)
        if name == "packed":  # bits packed from another shape are refused, not reinterpreted
            widened = jax.tree.map(lambda x: jnp.zeros((2, *x.shape), bool) if x.dtype == bool
                                   else x, runner)
            with pytest.raises(ValueError, match=r"cannot be read \(.* is stored as \(\d+,?\d*"):
                runs.load_checkpoint(tmp_path / "packed.msgpack", widened)
        for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(
                loaded.replace(key=jax.random.key_data(loaded.key))), strict=True):
            assert np.asarray(a).dtype == np.asarray(b).dtype
            np.testing.assert_array_equal(a, b)


def test_checkpoints_with_the_per_parameter_optimizer_state_still_resume(tmp_path):
    """Adam's moments stored per parameter (before `optax.flatten`) load as the flat vectors
    the optimizer keeps now, per seed, in the order it ravels the parameters."""
    import optax
    from jax.flatten_util import ravel_pytree

    _, _, method, config = experiment.build("genz", "LetterLTL0-v0", {"num_envs": 4, "num_steps": 8},
                                            None, jax.random.key(0))
    trainer = make_train(config, method)
    runner = jax.jit(trainer.init)(jax.random.key(3))
    params = jax.tree.map(lambda x: jnp.stack([x, x + 1.0]), runner.params)  # two seeds
    per_leaf = optax.chain(optax.clip_by_global_norm(1.0), optax.adam(1e-3))
    old_state = jax.vmap(per_leaf.init)(params)
    leaves, tree = jax.tree.flatten(old_state[1][0].mu)
    moments = jax.tree.unflatten(tree, [jax.random.normal(jax.random.key(i), x.shape)
                                        for i, x in enumerate(leaves)])
    old_state = (old_state[0], (old_state[1][0]._replace(mu=moments, count=jnp.array([7, 7])),
                                *old_state[1][1:]))
    runs.save_checkpoint(tmp_path / "old.msgpack", runner.replace(params=params,
                                                                  opt_state=old_state))
    template = runner.replace(params=params, opt_state=jax.vmap(trainer.optimizer.init)(params))
    loaded = runs.load_checkpoint(tmp_path / "old.msgpack", template)
    adam = loaded.opt_state[1][0]
    np.testing.assert_array_equal(adam.mu, jax.vmap(lambda m: ravel_pytree(m)[0])(moments))
    np.testing.assert_array_equal(adam.nu, np.zeros_like(adam.nu))
    np.testing.assert_array_equal(adam.count, [7, 7])


def test_checkpoints_without_step_planes_still_load():
    """A state dict written before specs carried `step_planes` (here: two stacked specs, as
    in a runner's per-env task states) gets them derived from `step_table` on load."""
    from flax import serialization

    from specrl_jax.automata import compile_spec, stack, zero_or_one

    specs = stack([compile_spec(f, ("a", "b"), zero_or_one(2)) for f in ("F a", "!b U a")])
    old = serialization.to_state_dict(jax.device_get(specs))
    del old["step_planes"]
    loaded = serialization.from_state_dict(specs, runs.add_derived_spec_fields({"env": old})["env"])
    for a, b in zip(jax.tree.leaves(specs), jax.tree.leaves(loaded)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


SHARDED = textwrap.dedent(
    """
    import sys, jax, numpy as np
    sys.path.insert(0, {here!r})
    from chain import ChainMethod
    from specrl_jax.baselines.ppo import PPOConfig, env_mesh, make_train
    assert jax.device_count() == 2
    cfg = PPOConfig(num_envs=4, num_steps=8, total_timesteps=4 * 8 * 3, update_epochs=2,
                    num_minibatches=2, loss="rco", target_kl=0.5)
    key = jax.random.key(7)
    plain, m_plain = jax.jit(make_train(cfg, ChainMethod()))(key)
    sharded, m_sharded = jax.jit(make_train(cfg, ChainMethod(), mesh=env_mesh()))(key)
    assert len(sharded.obs.sharding.device_set) == 2, sharded.obs.sharding
    for a, b in zip(jax.tree.leaves(plain.params), jax.tree.leaves(sharded.params)):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(m_plain["successes"], m_sharded["successes"])
    print("OK")
    """
)


def test_sharded_and_unsharded_runs_agree():
    env = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).parents[2]), env.get("PYTHONPATH", "")])
    code = SHARDED.format(here=str(Path(__file__).parent))
    proc = subprocess.run([sys.executable, "-c", code], check=False, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "OK" in proc.stdout, proc.stderr[-3000:]
