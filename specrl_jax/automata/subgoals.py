"""One-step reach-avoid subgoals of every automaton state, precomputed on the host as padded arrays.

For each state, every labelled transition to another live state (reach = the symbols leading
there, target = that state) plus, where the state has an accepting self-loop, "take it" (target =
the state itself); avoid = the symbols leading to the dead sink. Epsilon transitions give no
one-step subgoal. These are what GenZ-LTL and GCRL-LTL condition on; DeepLTL's candidate
sequences are in `candidates`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from specrl_jax.automata.translate import Automaton


@dataclasses.dataclass(frozen=True)
class Subgoals:
    """One-step subgoals: reach/avoid bool[S, G, A], target int32[S, G] (-1 unused), valid bool[S, G]."""

    reach: np.ndarray
    avoid: np.ndarray
    target: np.ndarray
    valid: np.ndarray


def one_step_subgoals(aut: Automaton) -> Subgoals:
    """Every labelled way out of each live state, plus its accepting self-loop if any."""
    per_state = []
    for q in range(aut.num_states):
        row, goals = aut.delta[q], []
        if not (aut.violation[q] or (aut.is_finite and aut.success[q])):
            for t in sorted(set(row.tolist()) - {q}):
                if not aut.violation[t]:
                    goals.append((t, row == t))
            loop = (row == q) & aut.accepting[q]
            if loop.any():
                goals.append((q, loop))
        per_state.append((goals, aut.violation[row]))
    num_goals = max(1, max(len(g) for g, _ in per_state))
    shape = (aut.num_states, num_goals)
    reach = np.zeros(shape + (aut.delta.shape[1],), dtype=bool)
    avoid = np.zeros_like(reach)
    target = np.full(shape, -1, dtype=np.int32)
    for q, (goals, dead) in enumerate(per_state):
        for g, (t, mask) in enumerate(goals):
            reach[q, g], avoid[q, g], target[q, g] = mask, dead, t
    return Subgoals(reach=reach, avoid=avoid, target=target, valid=target >= 0)
