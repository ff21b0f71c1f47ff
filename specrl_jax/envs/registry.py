"""Env IDs -> constructors, as one explicit table, and the one place where an ID's overrides
are validated. Importing a world module registers nothing: each world family exposes
`env_ids() -> {env_id: (factory, description, overrides)}`, and the table below lists the
families. Variants are entries over configs, never subclasses. A family's `env_ids()` stays
cheap (no MuJoCo, MJX or JAX where it can): listing IDs imports no physics, and `overrides` may
be a function returning the `Overrides`, so that the world's modules load at `make`.

`make(env_id, **overrides)` checks the ID (close matches on a typo) and, where the entry
declares its `Overrides`, every override name and `max_steps` before any world is built; the
family's factory then only splits the overrides into config and params fields and builds.
A family's config-based builder (`make_zone(config, **params)`, ...) checks its params with
the same `Overrides.check_params`.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import importlib
from collections.abc import Callable
from typing import Any

Factory = Callable[..., tuple[Any, Any]]

#: world families: module path of each family's `env_ids()`, in listing order
FAMILIES: tuple[str, ...] = (
    "specrl_jax.envs.letter",
    "specrl_jax.envs.zone",
    "specrl_jax.envs.arm",
    "specrl_jax.envs.multi",
)


@dataclasses.dataclass(frozen=True)
class Overrides:
    """What `make(env_id, **overrides)` accepts for an entry: the init fields of `config` that
    the ID does not fix, and the params fields `param_fields` (`max_steps`: a positive int).

    Attributes:
        config: the family's frozen config dataclass (named in messages).
        params: the family's params dataclass (named in messages).
        fixed: names the env ID fixes (config fields it sets, or parts of the ID such as
            `level`); overriding one raises, pointing to the custom-config builder.
        param_fields: the params fields an override may set.
    """

    config: type
    params: type
    fixed: tuple[str, ...] = ()
    param_fields: tuple[str, ...] = ("max_steps",)

    @property
    def config_fields(self) -> tuple[str, ...]:
        """The config fields an override may set, sorted."""
        return tuple(sorted(f.name for f in dataclasses.fields(self.config)
                            if f.init and f.name not in self.fixed))

    def split(self, overrides: dict[str, Any],
              env_id: str | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        """`(config overrides, params overrides)`; `ValueError` for a name the ID fixes, an
        unknown name (listing the accepted ones) or a bad `max_steps`."""
        fixed = sorted(set(overrides) & set(self.fixed))
        if fixed:
            raise ValueError(
                f"{fixed} are fixed by the env ID {env_id!r}; pick another ID, or build a custom "
                f"world from your own {self.config.__name__}"
            )
        config_fields = set(self.config_fields)
        config_kw = {k: v for k, v in overrides.items() if k in config_fields}
        params_kw = {k: v for k, v in overrides.items() if k not in config_fields}
        self.check_params(params_kw, env_id, with_config=True)
        return config_kw, params_kw

    def check_params(self, params: dict[str, Any], env_id: str | None = None,
                     with_config: bool = False) -> None:
        """`ValueError` for a name outside `param_fields` (and, `with_config`, the config
        fields) or a `max_steps` that is not a positive int."""
        accepted = list(self.param_fields) + (list(self.config_fields) if with_config else [])
        unknown = sorted(set(params) - set(self.param_fields))
        if unknown:
            nor = f" (nor {self.config.__name__} fields)" if with_config else ""
            where = f" for {env_id!r}" if env_id is not None else ""
            config = f"{self.config.__name__} fields {list(self.config_fields)} and " if with_config else ""
            close = {c for name in unknown for c in difflib.get_close_matches(name, accepted, n=2)}
            hint = f" (did you mean {', '.join(repr(c) for c in sorted(close))}?)" if close else ""
            raise ValueError(
                f"unknown {self.params.__name__} fields {unknown}{nor}{where}; accepted: {config}"
                f"{self.params.__name__} fields {list(self.param_fields)}{hint}"
            )
        max_steps = params.get("max_steps", 1)
        if not isinstance(max_steps, int) or isinstance(max_steps, bool) or max_steps < 1:
            raise ValueError(f"max_steps must be a positive int, got {max_steps!r}")


Entry = tuple[Factory, str, "Overrides | Callable[[], Overrides] | None"]

_EXTRA: dict[str, Entry] = {}


@functools.cache
def _family_table() -> dict[str, Entry]:
    table: dict[str, Entry] = {}
    for module in FAMILIES:
        for env_id, entry in importlib.import_module(module).env_ids().items():
            if env_id in table:
                raise RuntimeError(f"env ID {env_id!r} is declared by two families")
            factory, description, *overrides = entry
            table[env_id] = (factory, description, overrides[0] if overrides else None)
    return table


def _table() -> dict[str, Entry]:
    return {**_family_table(), **_EXTRA}


def register(env_id: str, factory: Factory, description: str = "",
             overrides: Overrides | None = None) -> None:
    """Add a user's own `factory(**overrides) -> (env, params)` under `env_id`; with
    `overrides`, `make` validates the override names first (else the factory does)."""
    if env_id in _table():
        raise ValueError(f"env ID {env_id!r} is already registered")
    _EXTRA[env_id] = (factory, description, overrides)


def unregister(env_id: str) -> None:
    """Remove an ID added by `register` (the built-in IDs stay)."""
    _EXTRA.pop(env_id, None)


def list_envs() -> list[str]:
    """All registered env IDs, sorted."""
    return sorted(_table())


def describe(env_id: str) -> str:
    """The one-line description of a registered ID."""
    return _table()[_checked_id(env_id)][1]


def make(env_id: str, **overrides: Any) -> tuple[Any, Any]:
    """Build `(env, params)` for a registered ID; `overrides` change config or params fields
    (validated first: unknown names are listed with the accepted ones)."""
    factory, _, accepted = _table()[_checked_id(env_id)]
    if callable(accepted):
        accepted = accepted()
    if accepted is not None:
        accepted.split(overrides, env_id)
    return factory(**overrides)


def _checked_id(env_id: str) -> str:
    if not isinstance(env_id, str):
        raise TypeError(f"env ID must be a string, got {type(env_id).__name__}")
    table = _table()
    if env_id not in table:
        close = difflib.get_close_matches(env_id, list(table), n=3, cutoff=0.6)
        hint = f" Did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        raise ValueError(
            f"unknown env ID {env_id!r}.{hint} Known IDs: {', '.join(sorted(table))}"
        )
    return env_id
