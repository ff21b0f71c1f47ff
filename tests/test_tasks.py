"""The task layer on a tiny torus with hand-built automata: stepping, reward, termination,
epsilon steps, horizon and auto-reset."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from eval.tiny_world import (
    TinyParams,
    TinyWorld,
    persistence_spec,
    reach_avoid_spec,
    recurrence_spec,
    stack_specs,
)

from specrl_jax.tasks import TaskEnv

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3
PARAMS = TinyParams(max_steps=6)


def fixed_letters() -> jnp.ndarray:
    """a at (0, 1), b at (0, 2), c at (1, 0); the agent starts at (0, 0)."""
    letters = np.full((5, 5), -1, np.int8)
    letters[0, 1], letters[0, 2], letters[1, 0] = 0, 1, 2
    return jnp.asarray(letters)


@pytest.fixture(scope="module")
def task():
    return TaskEnv(TinyWorld(), stack_specs([reach_avoid_spec(), recurrence_spec(), persistence_spec()]))


@pytest.fixture(scope="module")
def step(task):
    return jax.jit(task.step)


def start(task, spec_index):
    _, state = task.reset(jax.random.key(0), PARAMS, spec_index)
    env_state = state.env_state.replace(letters=fixed_letters())
    return state.replace(env_state=env_state, obs=task.env._obs(env_state))


def play(step, state, actions, epsilons=None):
    """Step through `actions`; returns the list of (state, reward, terminated, truncated, info)."""
    out = []
    for i, action in enumerate(actions):
        take_epsilon = bool(epsilons[i]) if epsilons else False
        _, state, reward, terminated, truncated, info = step(
            jax.random.key(100 + i), state, jnp.int32(action), PARAMS, jnp.bool_(take_epsilon)
        )
        out.append((state, float(reward), bool(terminated), bool(truncated), info))
    return out


def test_reach_avoid_success_reward_and_auto_reset(task, step):
    state = start(task, 0)
    assert int(state.q) == 0 and int(state.time) == 0
    (s1, r1, t1, _, i1), (s2, r2, t2, tr2, i2) = play(step, state, [RIGHT, RIGHT])
    assert (int(s1.q), r1, t1) == (1, 1.0, False)  # reached a: progress
    assert np.array_equal(np.asarray(i1["propositions"]), [True, False, False])
    assert (r2, t2, tr2) == (1.0, True, False)
    assert bool(i2["success"]) and not bool(i2["violation"]) and int(i2["steps"]) == 2
    # auto-reset: fresh episode on the next spec, final observation of the success kept
    assert int(s2.time) == 0 and int(s2.spec_index) == 1 and int(s2.q) == 0
    assert int(i2["task"].spec_index) == 0
    assert int(np.asarray(i2["final_observation"]["ego"])[0, 2, 0]) == 1


def test_violation_ends_with_minus_one(task, step):
    (_, r1, t1, _, i1), = play(step, start(task, 0), [DOWN])
    assert (r1, t1) == (-1.0, True)
    assert bool(i1["violation"]) and not bool(i1["success"])


class RewardingWorld(TinyWorld):
    """The tiny world with a world reward of -0.5 on every step (a Zone wall crossing gives -1)."""

    def step_env(self, key, state, action, params):
        obs, state, _, terminated, info = super().step_env(key, state, action, params)
        return obs, state, jnp.float32(-0.5), terminated, info


def test_the_world_reward_passes_where_the_task_neither_progresses_nor_fails():
    """The task loop's reward is +1 / -1 on progress / violation and the world's own reward
    otherwise (`info["env_reward"]`); the training reward of LTL2Action, DeepLTL and
    RAD-Embeddings (`pass_world_reward`) keeps the world's reward likewise, on success only +1."""
    from specrl_jax.baselines.train_env import pass_world_reward

    task = TaskEnv(RewardingWorld(), stack_specs([reach_avoid_spec()]))
    step = jax.jit(task.step_task)
    records = play(step, start(task, 0), [UP, DOWN, RIGHT])  # two self-loops, then a (progress)
    assert [r for _, r, *_ in records] == [-0.5, -0.5, 1.0]
    assert [float(i["env_reward"]) for *_, i in records] == [-0.5, -0.5, -0.5]
    assert [float(pass_world_reward(i)) for *_, i in records] == [-0.5] * 3  # not complete
    state = start(task, 0)
    (_, r1, t1, _, i1), = play(step, state, [DOWN])  # violation: -1 whatever the world gives
    assert (r1, t1, float(pass_world_reward(i1))) == (-1.0, True, -1.0)
    *_, (_, r3, t3, _, i3) = play(step, state, [RIGHT, RIGHT])  # success
    assert (r3, t3, float(pass_world_reward(i3))) == (1.0, True, 1.0)


def test_self_loops_give_no_reward_and_count_steps_in_q(task):
    state = start(task, 0)
    (s1, r1, *_), (s2, r2, *_) = play(jax.jit(task.step_task), state, [UP, UP])
    assert (r1, r2) == (0.0, 0.0)
    assert (int(s1.steps_in_q), int(s2.steps_in_q)) == (1, 2)


def test_infinite_spec_counts_accepting_visits_and_runs_to_horizon(task, step):
    state = start(task, 1)
    # a, b (accepting), a, b (accepting), left, left: the horizon of 6 ends it
    records = play(step, state, [RIGHT, RIGHT, LEFT, RIGHT, DOWN, UP])
    rewards = [r for _, r, *_ in records]
    assert rewards == [1.0, 1.0, 1.0, 1.0, 0.0, 0.0]
    assert [bool(i["accepted"]) for *_, i in records] == [False, True, False, True, False, False]
    assert not any(t for _, _, t, _, _ in records[:5])
    _, _, terminated, truncated, info = records[-1]
    assert truncated and not terminated
    assert int(info["num_accepting_visits"]) == 2 and not bool(info["success"])


def test_epsilon_step_keeps_the_world_and_counts_toward_the_horizon(task):
    step_task = jax.jit(task.step_task)
    state = start(task, 2)
    (s1, r1, t1, _, i1), = play(step_task, state, [RIGHT], epsilons=[True])
    assert bool(i1["epsilon"]) and int(s1.q) == 1 and r1 == 0.0 and not t1
    assert np.array_equal(np.asarray(s1.env_state.agent), [0, 0])  # world not stepped
    assert int(s1.env_state.time) == 0 and int(s1.time) == 1
    # in state 1 there is no epsilon edge: the request is ignored and the world steps
    (s2, r2, _, _, i2), = play(step_task, s1, [RIGHT], epsilons=[True])
    assert not bool(i2["epsilon"]) and np.array_equal(np.asarray(s2.env_state.agent), [0, 1])
    assert bool(i2["accepted"]) and r2 == 1.0
    (s3, r3, t3, _, i3), = play(step_task, s2, [LEFT])
    # an empty cell kills the jumped run, not `F G a`: back to state 0, the run that never jumped
    assert not t3 and r3 == 0.0 and not bool(i3["violation"]) and int(s3.q) == 0
    # five world steps in state 0, then an epsilon step: the sixth step hits the horizon
    records = play(step_task, state, [UP] * 6, epsilons=[False] * 5 + [True])
    assert [tr for _, _, _, tr, _ in records] == [False] * 5 + [True]
    assert bool(records[-1][4]["epsilon"]) and int(records[-1][0].env_state.time) == 5


def test_reset_draws_layouts_and_specs(task):
    keys = jax.random.split(jax.random.key(3), 16)
    _, states = jax.jit(jax.vmap(task.reset, in_axes=(0, None)))(keys, PARAMS)
    layouts = np.asarray(states.env_state.letters).reshape(16, -1)
    assert len({row.tobytes() for row in layouts}) > 1
    assert len(set(np.asarray(states.spec_index).tolist())) > 1
    np.testing.assert_array_equal(np.asarray(states.q), np.asarray(states.spec.init))


def test_batched_step_equals_single_steps(task, step):
    keys = jax.random.split(jax.random.key(5), 4)
    _, states = jax.jit(jax.vmap(task.reset, in_axes=(0, None, 0)))(keys, PARAMS, jnp.arange(4) % 3)
    actions = jnp.array([RIGHT, DOWN, LEFT, UP])
    step_keys = jax.random.split(jax.random.key(6), 4)
    batched = jax.jit(jax.vmap(task.step, in_axes=(0, 0, 0, None)))(step_keys, states, actions, PARAMS)
    for i in range(4):
        state_i = jax.tree.map(lambda x, i=i: x[i], states)
        single = step(step_keys[i], state_i, actions[i], PARAMS)
        for got, want in zip(jax.tree.leaves(single[1:5]), jax.tree.leaves(batched[1:5])):
            np.testing.assert_array_equal(np.asarray(got), np.asarray(want)[i])


def test_rejects_specs_of_another_alphabet():
    spec = reach_avoid_spec()
    wrong = spec.replace(delta=spec.delta[:, :3], accepting=spec.accepting[:, :3])
    with pytest.raises(ValueError, match="alphabet"):
        TaskEnv(TinyWorld(), stack_specs([wrong]))
    with pytest.raises(ValueError, match="stacked"):
        TaskEnv(TinyWorld(), spec)


def test_spot_compiled_spec_behaves_as_the_hand_built_one():
    from specrl_jax import automata

    world = TinyWorld()
    compiled = automata.compile_spec("!c U (a & F b)", world.propositions, alphabet=world.alphabet)
    task = TaskEnv(world, automata.stack([compiled]))
    step = jax.jit(task.step_task)
    (_, r1, t1, _, _), (_, r2, t2, _, i2) = play(step, start(task, 0), [RIGHT, RIGHT])
    assert (r1, t1, r2, t2, bool(i2["success"])) == (1.0, False, 1.0, True, True)
    (_, r, t, _, info), = play(step, start(task, 0), [DOWN])
    assert (r, t, bool(info["violation"])) == (-1.0, True, True)


def test_epsilon_slot_chooses_among_several_epsilon_edges():
    from specrl_jax import automata

    world = TinyWorld()
    props = world.propositions
    compiled = automata.compile_spec(f"(FG {props[0]}) | (GF {props[1]} & GF {props[2]})", props,
                                     alphabet=world.alphabet)
    targets = np.asarray(compiled.epsilon)[int(compiled.init)]
    assert (targets >= 0).sum() == 2 and targets[0] != targets[1]
    task = TaskEnv(world, automata.stack([compiled]))
    for slot in (0, 1):
        state = start(task, 0)
        _, state, _, _, _, info = jax.jit(task.step_task)(
            jax.random.key(0), state, RIGHT, None, jnp.int32(slot))
        assert bool(info["epsilon"]) and int(state.q) == targets[slot]


def test_epsilon_slot_past_the_last_is_a_world_step(task):
    """A slot the state lacks (here past the only one) is ignored: the world steps, q follows
    the label, as the automaton step does."""
    step_task = jax.jit(task.step_task)
    state = start(task, 2)
    _, moved, _, _, _, info = step_task(jax.random.key(3), state, jnp.int32(RIGHT), PARAMS,
                                        jnp.int32(state.spec.epsilon.shape[-1]))
    assert not bool(info["epsilon"]) and int(moved.env_state.time) == 1
    assert np.array_equal(np.asarray(moved.env_state.agent), [0, 1]) and int(moved.q) == 0


class EditedInfo:
    """An env whose step info passes through `edit`."""

    def __init__(self, env, edit):
        self.env, self.edit = env, edit

    def __getattr__(self, name):
        return getattr(self.env, name)

    def step(self, *args):
        *out, info = self.env.step(*args)
        return (*out, self.edit(info))


def test_env_symbol_runs_the_automaton_as_the_label_does():
    """LetterWorld reports `info["symbol"]`, which the task layer steps from; dropping it (so
    that the label is looked up) gives the same runs over episodes, resets and several specs."""
    import specrl_jax
    from specrl_jax import automata

    env, params = specrl_jax.make("LetterLTL0-v0")
    # resets from a bank of maps: the exact sampler, run on every step of the vmapped scan,
    # would take most of the test's time
    params = env.with_map_bank(jax.random.key(1), params, num_maps=64)
    formulas = ["F a & F b", "!c U (d & F e)", "GF a & GF b", "G !f & F (g | h)"]
    specs = automata.compile_suite(formulas, env.propositions, env.alphabet)

    def run(task):
        def body(state, key):
            actions = jax.random.randint(key, (32,), 0, 4)
            _, state, reward, terminated, _, info = jax.vmap(task.step, (0, 0, 0, None))(
                jax.random.split(key, 32), state, actions, params)
            return state, (state.q, reward, terminated, info["accepted"])

        keys = jax.random.split(jax.random.key(0), 32)
        @jax.jit
        def episodes(keys):
            _, state = jax.vmap(task.reset, (0, None, 0))(keys, params, jnp.arange(32) % 4)
            return jax.lax.scan(body, state, jax.random.split(keys[0], 120))[1]

        return episodes(keys)

    with_symbol = run(TaskEnv(env, specs))
    without = run(TaskEnv(EditedInfo(env, lambda i: {"propositions": i["propositions"]}), specs))
    for got, want in zip(with_symbol, without):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    # the symbol is what the automaton reads: a wrong one changes the runs
    shifted = run(TaskEnv(EditedInfo(env, lambda i: {**i, "symbol": (i["symbol"] + 1) % 13}),
                          specs))
    assert (np.asarray(shifted[0]) != np.asarray(with_symbol[0])).any()
    _, reward, terminated, accepted = (np.asarray(x) for x in with_symbol)
    assert (reward > 0).sum() > 20 and terminated.sum() > 5 and accepted.sum() > 5


def test_task_state_holds_an_index_into_the_specs_not_a_copy(task):
    """A batch of task states carries one spec index per env; `state.spec` reads the stacked
    specs at that index."""
    keys = jax.random.split(jax.random.key(7), 8)
    _, states = jax.vmap(task.reset, in_axes=(0, None, 0))(keys, PARAMS, jnp.arange(8) % 3)
    per_env = jax.tree.leaves(states.replace(env_state=None, obs=None))
    assert max(leaf.size for leaf in per_env) <= 8 * task.env.num_propositions
    want = jax.tree.map(lambda leaf: leaf[jnp.arange(8) % 3], task.specs)
    for got, expected in zip(jax.tree.leaves(states.spec), jax.tree.leaves(want), strict=True):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(expected))


def test_specs_over_a_reordered_alphabet_read_the_label():
    """The env's symbol is a row of its own alphabet; specs compiled over the same assignments
    in another order must not take it as theirs (the step looks the label up instead)."""
    import specrl_jax
    from specrl_jax import automata

    env, params = specrl_jax.make("LetterLTL0-v0")
    letters = np.full((7, 7), -1, np.int8)
    letters[0, 1] = 0  # a, right of the agent
    _, world = env.reset_to(jax.random.key(0), {"letters": letters, "agent": np.zeros(2, np.int32)})
    for alphabet in (np.asarray(env.alphabet), np.asarray(env.alphabet)[::-1]):
        spec = automata.compile_spec("F a", env.propositions, alphabet=alphabet)
        task = TaskEnv(env, automata.stack([spec]))
        _, state = task.reset(jax.random.key(0), params, 0)
        info = task.step_task(jax.random.key(1), state.replace(env_state=world), jnp.int32(RIGHT),
                              params)[-1]
        assert bool(info["success"])


def test_task_states_of_equal_specs_share_their_structure():
    specs = stack_specs([reach_avoid_spec(), recurrence_spec()])
    states = [TaskEnv(TinyWorld(), s).reset(jax.random.key(0), PARAMS, 0)[1]
              for s in (specs, stack_specs([reach_avoid_spec(), recurrence_spec()]),
                        stack_specs([reach_avoid_spec()]))]
    assert jax.tree.structure(states[0]) == jax.tree.structure(states[1])
    assert jax.tree.structure(states[0]) != jax.tree.structure(states[2])
