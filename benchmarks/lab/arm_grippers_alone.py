"""Can the grippers-and-arm Arm touch a sphere with its fingers and not with its hand?

On `PandaLTLReach1-v0` (end-effector control, mode 1) a scripted controller drives the grasp
target in a straight line to a point `--heights` above the centre of each episode's first
sphere (`action = clip((goal - grasp) / 0.05, -1, 1)`) for `--steps` steps. Per height it
reports the share of episodes whose `grippers_<colour>` ever holds, of those whose
`arm_<colour>` (the hand is an arm link) holds at or before that first step, and of those
where `grippers_<colour>` holds without `arm_<colour>` at some step: whether "reach
`grippers_c` while avoiding `arm_c`", a task of the Zone curriculum over the arm's 8
propositions, can be done at all, and how often a direct approach fails it. One JSON row per
height (`benchmarks/harness.py`; appended to `--out` if given).

    python benchmarks/lab/arm_grippers_alone.py --episodes 24 --steps 60
"""

from __future__ import annotations

import argparse
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import harness

import specrl_jax

ENV_ID = "PandaLTLReach1-v0"
ACTION_SCALE = 0.05  # metres of grasp-target motion per unit action (end-effector control)


def approach(env, params, episodes: int, steps: int, height: float, seed: int) -> np.ndarray:
    """bool[steps, episodes, P]: the labels while the grasp target goes straight to `height`
    metres above each episode's first sphere."""
    keys = jax.random.split(jax.random.key(seed), episodes)
    _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
    lift = jnp.array([0.0, 0.0, height], jnp.float32)

    def step(state, _):
        grasp = jax.vmap(lambda s: env.poses(s)["grasp_pos"])(state)
        action = jnp.clip((state.region_pos[:, 0] + lift - grasp) / ACTION_SCALE, -1.0, 1.0)
        _, state, _, _, info = jax.vmap(env.step_env, in_axes=(None, 0, 0, None))(
            jax.random.key(0), state, action, params)
        return state, info["propositions"]

    return np.asarray(jax.jit(lambda s: jax.lax.scan(step, s, None, length=steps)[1])(state))


def shares(labels: np.ndarray, arm: int, grippers: int) -> dict[str, float]:
    fingers, hand = labels[:, :, grippers], labels[:, :, arm]
    reached = fingers.any(0)
    first = fingers.argmax(0)
    hand_first = np.array([hand[: first[n] + 1, n].any() for n in range(labels.shape[1])])
    return {"grippers_reached": float(reached.mean()),
            "arm_at_or_before_grippers": float(hand_first[reached].mean()) if reached.any() else None,
            "grippers_without_arm": float((fingers & ~hand).any(0).mean())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=24)
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--heights", type=float, nargs="+", default=[0.0, 0.03, 0.06],
                        help="metres above the sphere's centre the grasp target goes to")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="append the JSON rows to this file")
    args = parser.parse_args()
    env, params = specrl_jax.make(ENV_ID)
    colour = env.config.colors[int(env.region_color[0])]
    arm, grippers = env.propositions.index(f"arm_{colour}"), env.propositions.index(f"grippers_{colour}")
    for height in args.heights:
        found = shares(approach(env, params, args.episodes, args.steps, height, args.seed), arm, grippers)
        value = ", ".join(f"{k} {v:.2f}" if v is not None else f"{k} -" for k, v in found.items())
        print(f"height {height:.2f} m: {value}", flush=True)
        harness.emit(harness.row(f"{ENV_ID}, straight approach to {height:.2f} m above a sphere",
                                 value, args.episodes, height=height, colour=colour, **found),
                     args.out)


if __name__ == "__main__":
    main()
