"""The multi-agent world's joint propositions through the automata layer: the paper's
multi-agent suites compile over PointLTL0MA2-v0's propositions and alphabet, and an automaton
steps on labels the world itself produces."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import specrl_jax
from specrl_jax import automata, specs

# zone centres in placement order: green x2, yellow x2, blue x2, magenta x2
ZONES = np.array([[-2.0, -2.0], [2.0, 2.0], [2.0, -2.0], [-2.0, 2.0],
                  [0.0, 1.5], [0.0, -1.5], [-1.5, 0.0], [1.5, 0.0]], np.float32)
AT = {"none": (0.0, 0.0), "blue": (0.0, 1.5), "magenta": (1.5, 0.0), "green": (2.0, 2.0),
      "yellow": (-2.0, 2.0), "none2": (0.0, 0.6)}


@pytest.fixture(scope="module")
def world():
    env, params = specrl_jax.make("PointLTL0MA2-v0")
    reset_to, label = jax.jit(env.reset_to), jax.jit(env.label)
    layout = {
        "agent_yaw": jnp.zeros(2), "zone_xy": jnp.asarray(ZONES),
        "zone_color": jnp.asarray(env.world.zone_color),
        "zone_radius": jnp.asarray(env.world.zone_radius),
        "zone_direction": jnp.zeros(8), "zone_phase": jnp.zeros(8),
    }

    def world_label(where_0: str, where_1: str) -> np.ndarray:
        agent_xy = jnp.asarray([AT[where_0], AT[where_1]], jnp.float32)
        _, state = reset_to(jax.random.key(0), dict(layout, agent_xy=agent_xy), params)
        return np.asarray(label(state))

    return env, world_label


def test_paper_suites_compile_over_the_joint_propositions(world):
    env, _ = world
    alphabet = np.asarray(env.alphabet)
    names = [n for n in specs.list_suites() if n.startswith("multi_agent_zone/")]
    assert len(names) == 6
    for name in names:
        info = specs.suite_info(name)
        assert info.propositions == env.propositions
        for formula in info.formulas:
            with warnings.catch_warnings():  # three specs exceed the candidate caps (fidelity.md)
                warnings.filterwarnings("ignore", message=".*candidate sequences dropped")
                spec = automata.compile_spec(formula, env.propositions, alphabet=alphabet)
            np.testing.assert_array_equal(spec.alphabet, alphabet)
    with pytest.raises(ValueError, match="blue_2"):
        automata.compile_spec("F blue_2", env.propositions, alphabet=alphabet)


def test_an_automaton_steps_on_the_worlds_joint_labels(world):
    env, world_label = world
    # paper indep[0]: agent 0 blue then green avoiding magenta and yellow; agent 1 magenta then
    # yellow avoiding blue and green
    formula = specs.suite("multi_agent_zone/finite/indep")[0]
    spec = automata.compile_spec(formula, env.propositions, alphabet=np.asarray(env.alphabet))
    names = lambda label: {p for p, on in zip(env.propositions, label) if on}

    def run(path):
        q, flags = spec.init, []
        for where_0, where_1 in path:
            label = world_label(where_0, where_1)
            q, _, success, violation = automata.step(spec, q, jnp.asarray(label), False)
            flags.append((names(label), bool(success), bool(violation)))
        return flags

    flags = run([("none", "none2"), ("blue", "magenta"), ("none", "none2"), ("green", "none2"),
                 ("green", "yellow")])
    assert [f[0] for f in flags] == [set(), {"blue_0", "magenta_1"}, set(), {"green_0"},
                                     {"green_0", "yellow_1"}]
    assert [f[1] for f in flags] == [False, False, False, False, True]
    assert not any(f[2] for f in flags)
    flags = run([("none", "none2"), ("magenta", "none2")])  # agent 0 in an avoided zone
    assert flags[-1] == ({"magenta_0"}, False, True)
    flags = run([("blue", "blue")])  # agent 1 in one of its avoided zones
    assert flags[-1] == ({"blue_0", "blue_1"}, False, True)
