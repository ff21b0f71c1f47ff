"""Graph facts about small automata, computed on the host with numpy.

Every function takes dense successor tables (`int32[S, A]`, with optional epsilon successors
`int32[S, E]`, -1 = none) and returns boolean per-state or per-transition facts. Automata here
have at most a few hundred states, so a dense reachability matrix is simpler than Tarjan and
fast enough.
"""

from __future__ import annotations

import numpy as np


def adjacency(delta: np.ndarray, epsilon: np.ndarray | None = None) -> np.ndarray:
    """`bool[S, S]`: `adj[i, j]` iff some symbol (or epsilon edge) leads from i to j."""
    num_states = delta.shape[0]
    adj = np.zeros((num_states, num_states), dtype=bool)
    rows = np.repeat(np.arange(num_states), delta.shape[1])
    adj[rows, delta.reshape(-1)] = True
    if epsilon is not None:
        src, slot = np.nonzero(epsilon >= 0)
        adj[src, epsilon[src, slot]] = True
    return adj


def reachability(adj: np.ndarray) -> np.ndarray:
    """`bool[S, S]`: reflexive-transitive closure (Warshall), `reach[i, j]` iff j reachable from i."""
    reach = adj | np.eye(adj.shape[0], dtype=bool)
    for k in range(adj.shape[0]):
        reach |= reach[:, k : k + 1] & reach[k : k + 1, :]
    return reach


def internal(delta: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """`bool[S, A]`: the transition q -a-> delta[q, a] lies inside an SCC (its target reaches q)."""
    return reach[delta, np.arange(delta.shape[0])[:, None]]


def nonempty(
    delta: np.ndarray, accepting: np.ndarray, epsilon: np.ndarray | None = None
) -> np.ndarray:
    """`bool[S]`: some word (and epsilon timing) from this state takes accepting edges forever.

    That holds iff the state reaches a cycle containing an accepting transition.
    """
    reach = reachability(adjacency(delta, epsilon))
    on_cycle = (accepting & internal(delta, reach)).any(axis=1)
    return (reach & on_cycle[None, :]).any(axis=1)


def has_bad_cycle(delta: np.ndarray, allowed: np.ndarray, marked: np.ndarray) -> np.ndarray:
    """`bool[S]`: the state reaches (by any edge) a cycle of `allowed` edges that uses a `marked` one.

    Args:
        delta: int32[S, A] successors.
        allowed: bool[S, A] edges the cycle may use.
        marked: bool[S, A] edges of which the cycle must use at least one (subset of `allowed`).
    """
    num_states = delta.shape[0]
    sub = np.zeros((num_states, num_states), dtype=bool)
    src, sym = np.nonzero(allowed)
    sub[src, delta[src, sym]] = True
    reach_sub = reachability(sub)
    cyc = marked & allowed & reach_sub[delta, np.arange(num_states)[:, None]]
    bad = cyc.any(axis=1)
    reach_all = reachability(adjacency(delta))
    return (reach_all & bad[None, :]).any(axis=1)


def dba_universal(delta: np.ndarray, accepting: np.ndarray) -> np.ndarray:
    """`bool[S]`: every infinite word from the state is accepted by the deterministic Buchi table.

    A word is rejected iff its run ends in a cycle of non-accepting transitions, so the state is
    universal iff it reaches no such cycle.
    """
    rejecting = ~accepting
    return ~has_bad_cycle(delta, rejecting, rejecting)


def parity_universal(delta: np.ndarray, color: np.ndarray) -> np.ndarray:
    """`bool[S]`: every word from the state is accepted by a complete min-even parity table.

    Args:
        delta: int32[S, A] successors (complete).
        color: int32[S, A] the colour of each transition.

    A word is rejected iff the least colour seen infinitely often is odd; the state is universal
    iff it reaches no cycle whose least colour is odd.
    """
    rejected = np.zeros(delta.shape[0], dtype=bool)
    for odd in range(1, int(color.max()) + 1, 2):
        rejected |= has_bad_cycle(delta, color >= odd, color == odd)
    return ~rejected


def bfs_order(init: int, delta: np.ndarray, epsilon: np.ndarray | None = None) -> list[int]:
    """States reachable from `init`, breadth-first, successors by symbol then epsilon slot."""
    order, seen = [init], {init}
    for state in order:
        succ = list(delta[state])
        if epsilon is not None:
            succ += [int(t) for t in epsilon[state] if t >= 0]
        for nxt in succ:
            if int(nxt) not in seen:
                seen.add(int(nxt))
                order.append(int(nxt))
    return order
