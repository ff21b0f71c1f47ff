"""LetterWorld: a torus grid of letters, the agent moves one cell per step (`LetterLTL0-v0`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from specrl_jax.envs import letter_maps
from specrl_jax.envs.base import Env, Info, Obs
from specrl_jax.envs.registry import Overrides
from specrl_jax.envs.spaces import Box, Dict, Discrete

# Row/column change of actions 0 up, 1 down, 2 left, 3 right (the original's order).
MOVES = np.array([[-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int32)


@dataclass(frozen=True)
class LetterConfig:
    """Shape-fixing settings of a LetterWorld.

    Attributes:
        grid_size: N, the world is an N x N torus (3 <= N <= 32).
        view_size: V, odd, the agent sees the V x V cells centred on itself (None: V = N).
        letters: proposition names, one per letter type.
        counts: cells per letter type (an int applies to every letter).

    Raises `ValueError` for letter densities at which valid maps are too rare for the exact
    sampler: fewer than `letter_maps.MIN_VALID_RATE` (1 in 10,000) of the uniform placements
    of the letter cells, by a Monte Carlo estimate made once per (grid size, cell count).
    """

    grid_size: int = 7
    view_size: int | None = None
    letters: tuple[str, ...] = tuple("abcdefghijkl")
    counts: tuple[int, ...] | int = 2

    def __post_init__(self) -> None:
        n = self.grid_size
        if not isinstance(n, int) or isinstance(n, bool) or not 3 <= n <= letter_maps.MAX_GRID_SIZE:
            raise ValueError(
                f"grid_size must be an int in 3..{letter_maps.MAX_GRID_SIZE}, got {n!r}"
            )
        if self.view_size is None and n % 2 == 0:
            raise ValueError(
                f"grid_size must be odd for the full view (view_size=None) centred on the agent, "
                f"got {n}; give an odd view_size < {n} for a partial view"
            )
        view = n if self.view_size is None else self.view_size
        if (
            not isinstance(view, int) or isinstance(view, bool)
            or view < 1 or view % 2 == 0 or view > n
        ):
            raise ValueError(
                f"view_size must be an odd int in 1..grid_size={n} (the agent sits at the centre), "
                f"got {self.view_size!r}"
            )
        letters = tuple(self.letters)
        if not letters or not all(isinstance(a, str) and a for a in letters):
            raise ValueError(f"letters must be non-empty strings, got {self.letters!r}")
        if len(set(letters)) != len(letters):
            raise ValueError(f"letters must be distinct, got {letters!r}")
        object.__setattr__(self, "letters", letters)
        counts = (
            (self.counts,) * len(letters) if isinstance(self.counts, int) else tuple(self.counts)
        )
        if len(counts) != len(letters) or not all(
            isinstance(c, int) and not isinstance(c, bool) and c >= 1 for c in counts
        ):
            raise ValueError(
                f"counts must be a positive int or one positive int per letter ({len(letters)}), "
                f"got {self.counts!r}"
            )
        object.__setattr__(self, "counts", counts)
        if sum(counts) > n * n // 2:
            raise ValueError(
                f"{sum(counts)} letter cells do not fit a {n}x{n} grid: at most {n * n // 2} "
                "(valid maps keep the empty cells connected; denser maps are almost never valid)"
            )
        self._check_density(n, sum(counts))

    @staticmethod
    def _check_density(n: int, num_cells: int) -> None:
        valid, drawn, _ = letter_maps.valid_rate(n, num_cells)
        if valid / drawn < letter_maps.MIN_VALID_RATE:
            raise ValueError(
                f"{num_cells} letter cells on a {n}x{n} grid: valid maps (empty cells connected, "
                f"every letter next to an empty cell) are too rare to sample: {valid} of {drawn} "
                f"uniform placements were valid; the exact sampler needs at least 1 in "
                f"{round(1 / letter_maps.MIN_VALID_RATE):,}. Use fewer letter cells (counts) or "
                "a larger grid_size"
            )

    @property
    def view(self) -> int:
        """V, the side of the agent-centred view."""
        return self.grid_size if self.view_size is None else self.view_size

    @property
    def num_letters(self) -> int:
        return len(self.letters)

    @property
    def map_spec(self) -> letter_maps.MapSpec:
        slots = tuple(i for i, c in enumerate(self.counts) for _ in range(c))
        _, _, fallback = letter_maps.valid_rate(self.grid_size, len(slots))
        return letter_maps.MapSpec(self.grid_size, slots, fallback)


@struct.dataclass
class LetterParams:
    """Values that may vary without changing shapes.

    Attributes:
        max_steps: horizon, sets `truncated` (75 as in the original's training harness).
        map_bank: None (default: exact uniform maps at every reset) or int8[M, N, N] ordinal grids
            from `LetterWorld.with_map_bank`, the opt-in fast reset (see docs/fidelity.md).
    """

    max_steps: int = 75
    map_bank: jax.Array | None = None


@struct.dataclass
class LetterState:
    letters: jax.Array  # int8[N, N], letter index per cell, -1 empty
    agent: jax.Array  # int32[2], row and column
    time: jax.Array  # int32[], steps taken in this episode


class LetterWorld(Env):
    """Letters on a torus; the agent moves up/down/left/right with wrap-around.

    Observation: `ap` uint8[V, V, L] letter channels and `ego` uint8[V, V, 1] agent channel, the
        V x V cells centred on the agent (view cell (i, j) is world cell agent + (i, j) - V // 2).
    Action: Discrete(4), 0 up (row - 1), 1 down, 2 left, 3 right; letters are not obstacles.
    Labels: `info["propositions"]` bool[L], the letter under the agent after the move, and
        `info["symbol"]` int32[], its row of `alphabet`.
    Reward 0; `truncated` at `params.max_steps`; `terminated` only after an invalid action.
    Invalid actions: an eager call with an action outside 0..3 raises `ValueError`; under `jit`
        or `vmap` the step moves as action 0, ends the episode (`terminated`) and sets
        `info["invalid_action"]` (False on valid steps); `envs.checked(env)` raises instead.
    State: `LetterState` (letters int8[N, N], agent int32[2], time int32).
    """

    obs_kinds = {"ap": "grid", "ego": "grid"}
    family = "letter"

    def __init__(self, config: LetterConfig = LetterConfig()):
        if not isinstance(config, LetterConfig):
            raise TypeError(f"config must be a LetterConfig, got {type(config).__name__}")
        self.config = config
        self.propositions = config.letters
        self._map_spec = config.map_spec

    @property
    def default_params(self) -> LetterParams:
        return LetterParams()

    @property
    def action_space(self) -> Discrete:
        return Discrete(4)

    @property
    def observation_space(self) -> Dict:
        v, num_letters = self.config.view, self.config.num_letters
        return Dict(
            {
                "ap": Box(0, 1, (v, v, num_letters), jnp.uint8),
                "ego": Box(0, 1, (v, v, 1), jnp.uint8),
            }
        )

    @property
    def original_observation_space(self) -> Any:
        """The original layout, gymnasium Box uint8[V, V, L + 1] (letters, then the agent)."""
        import gymnasium

        v = self.config.view
        return gymnasium.spaces.Box(0, 1, (v, v, self.config.num_letters + 1), np.uint8)

    def original_observation(self, obs: Obs) -> jax.Array:
        """Our obs dict -> the original uint8[V, V, L + 1]."""
        return jnp.concatenate([obs["ap"], obs["ego"]], axis=-1)

    @property
    def alphabet(self) -> jax.Array:
        """bool[L + 1, L]: row 0 no letter, row i letter i - 1."""
        num_letters = self.config.num_letters
        return jnp.concatenate(
            [jnp.zeros((1, num_letters), bool), jnp.eye(num_letters, dtype=bool)], axis=0
        )

    def with_map_bank(
        self, key: jax.Array, params: LetterParams | None = None, num_maps: int = 65536
    ) -> LetterParams:
        """Params whose resets draw from a bank of `num_maps` exactly sampled maps.

        Each reset takes a uniform bank entry under a uniform symmetry of the torus fixing the
        start (8 of them) with a fresh uniform labelling: every single map is still uniform over
        valid maps, but geometries repeat across resets (at most 8 x num_maps distinct).
        """
        if not isinstance(num_maps, int) or num_maps < 1:
            raise ValueError(f"num_maps must be a positive int, got {num_maps!r}")
        params = self.default_params if params is None else params
        bank = jax.jit(letter_maps.sample_bank, static_argnums=(1, 2))(
            key, self._map_spec, num_maps
        )
        return params.replace(map_bank=bank)

    def reset_env(self, key: jax.Array, params: LetterParams) -> tuple[Obs, LetterState]:
        if params.map_bank is None:
            letters = letter_maps.sample_letters(key, self._map_spec)
        else:
            letters = letter_maps.letters_from_bank(key, params.map_bank, self._map_spec)
        state = LetterState(letters, jnp.zeros((2,), jnp.int32), jnp.zeros((), jnp.int32))
        return self.observe(state), state

    def step_env(
        self, key: jax.Array, state: LetterState, action: jax.Array, params: LetterParams
    ) -> tuple[Obs, LetterState, jax.Array, jax.Array, Info]:
        agent = (state.agent + jnp.asarray(MOVES)[action]) % self.config.grid_size
        state = state.replace(agent=agent, time=state.time + 1)
        obs = self.observe(state)
        # the view is centred on the agent, so its centre cell is `label(state)` without a
        # second read of the map
        centre = self.config.view // 2
        info = {"propositions": obs["ap"][centre, centre].astype(bool), "symbol": self.symbol(state)}
        return obs, state, jnp.zeros((), jnp.float32), jnp.asarray(False), info

    def observe(self, state: LetterState) -> Obs:
        """The agent-centred view: `ap` uint8[V, V, L], `ego` uint8[V, V, 1]."""
        v, n = self.config.view, self.config.grid_size
        # A window of the 2x2-tiled torus: a slice, which batches better than a per-cell gather.
        tiled = jnp.tile(state.letters, (2, 2))
        corner = (state.agent - v // 2) % n
        view = jax.lax.dynamic_slice(tiled, (corner[0], corner[1]), (v, v))
        ap = view[..., None] == jnp.arange(self.config.num_letters, dtype=jnp.int8)
        ego = jnp.zeros((v, v, 1), jnp.uint8).at[v // 2, v // 2, 0].set(1)
        return {"ap": ap.astype(jnp.uint8), "ego": ego}

    def label(self, state: LetterState) -> jax.Array:
        """bool[L]: the letter under the agent (none on an empty cell)."""
        return _letter_under(state) == jnp.arange(self.config.num_letters, dtype=jnp.int8)

    def symbol(self, state: LetterState) -> jax.Array:
        """int32[]: the row of `alphabet` equal to `label(state)` (0 on an empty cell, else the
        letter index + 1), what `automata.step` takes as `symbol`."""
        return (_letter_under(state) + 1).astype(jnp.int32)

    def layout(self, state: LetterState) -> dict[str, jax.Array]:
        """`letters` int32[N, N] (-1 empty, else the letter index) and `agent` int32[2] (row, col)."""
        return {"letters": state.letters.astype(jnp.int32), "agent": state.agent}

    def reset_to(
        self, key: jax.Array, layout: dict[str, Any], params: LetterParams | None = None
    ) -> tuple[Obs, LetterState]:
        """Start an episode from `layout` (as returned by `layout`); checked when concrete.

        The map is taken as given (letter counts and the validity rule are not enforced).
        """
        self._check_layout(layout)
        letters = jnp.asarray(layout["letters"]).astype(jnp.int8)
        agent = jnp.asarray(layout["agent"]).astype(jnp.int32)
        state = LetterState(letters, agent, jnp.zeros((), jnp.int32))
        return self.observe(state), state

    def _check_layout(self, layout: dict[str, Any]) -> None:
        n, num_letters = self.config.grid_size, self.config.num_letters
        if not isinstance(layout, dict) or set(layout) != {"letters", "agent"}:
            got = sorted(layout) if isinstance(layout, dict) else type(layout).__name__
            raise ValueError(f"layout must be a dict with keys ['agent', 'letters'], got {got}")
        for name, shape in (("letters", (n, n)), ("agent", (2,))):
            value = layout[name]
            if jnp.shape(value) != shape:
                raise ValueError(f"layout[{name!r}] has shape {jnp.shape(value)}; expected {shape}")
            if not jnp.issubdtype(jnp.result_type(value), jnp.integer):
                raise TypeError(
                    f"layout[{name!r}] has dtype {jnp.result_type(value)}; expected integers"
                )
            if isinstance(value, jax.core.Tracer):
                continue
            value = np.asarray(value)
            low, high = (-1, num_letters - 1) if name == "letters" else (0, n - 1)
            if value.min() < low or value.max() > high:
                raise ValueError(
                    f"layout[{name!r}] holds values in {value.min()}..{value.max()}; "
                    f"accepted {low}..{high}"
                )


def _letter_under(state: LetterState) -> jax.Array:
    """int8[]: the letter index of the agent's cell, -1 if empty."""
    return state.letters[state.agent[0], state.agent[1]]


#: what `make("LetterLTL0-v0...", **overrides)` and `make_letter_world` accept: every
#: LetterConfig field and `max_steps` (checked by `envs.registry.Overrides`)
OVERRIDES = Overrides(LetterConfig, LetterParams)


def make_letter_world(config: LetterConfig, **overrides: Any) -> tuple[LetterWorld, LetterParams]:
    """Build `(env, params)`; `overrides` replace LetterConfig or LetterParams fields."""
    config_kwargs, params_kwargs = OVERRIDES.split(overrides)
    env = LetterWorld(LetterConfig(**{**config.__dict__, **config_kwargs}))
    params = env.default_params
    return env, params.replace(**params_kwargs) if params_kwargs else params


def env_ids() -> dict[str, tuple[Any, str]]:
    """The LetterWorld registry entries (read by `envs.registry`)."""
    return {
        "LetterLTL0-v0": (
            lambda **kw: make_letter_world(LetterConfig(), **kw),
            "LetterWorld, 7x7 torus, 12 letters x 2, full agent-centred view",
            OVERRIDES,
        ),
        "LetterLTL0-v0.partial": (
            lambda **kw: make_letter_world(LetterConfig(grid_size=15, view_size=7), **kw),
            "LetterWorld, 15x15 torus, 12 letters x 2, 7x7 agent-centred view",
            OVERRIDES,
        ),
    }
