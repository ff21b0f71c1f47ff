"""Lazy package exports (PEP 562), so that importing a package leaves its heavy modules
(JAX, MuJoCo, MJX) unloaded until a name from them is used."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any


def exports(package: str, modules: dict[str, tuple[str, ...]]) -> Callable[[str], Any]:
    """A module `__getattr__` for `package` resolving each name from its module.

    Args:
        package: the package's `__name__`.
        modules: submodule name (relative to `package`) -> the names it exports.

    Returns:
        `__getattr__(name)`: imports the submodule defining `name` on first use; raises
        `AttributeError` for other names.
    """
    owner = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name: str) -> Any:
        if name not in owner:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{owner[name]}"), name)
        # bound on the package: later lookups skip this function, and a submodule of the same
        # name (`envs.checked`), which importing it bound there, no longer shadows the export
        setattr(sys.modules[package], name, value)
        return value

    return __getattr__
