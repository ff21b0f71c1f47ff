"""The one saved-parameter format: a pytree as flax msgpack, with an optional JSON file beside it
(same name, `.json`) saying how it was made. Run checkpoints, trained parameters and the shipped
pretrained encoders all use it."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import serialization

#: the shipped artefacts of the baselines (pretrained formula encoders)
DATA_DIR = Path(__file__).parent / "data"


def save_params(path: str | os.PathLike, tree: Any, meta: dict[str, Any] | None = None) -> None:
    """Write `tree` to `path` (through a temporary file, so a crash leaves the old file whole)
    and `meta`, if given, to the JSON beside it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(serialization.to_bytes(jax.device_get(tree)))
    os.replace(tmp, path)
    if meta is not None:
        path.with_suffix(".json").write_text(json.dumps(meta, indent=1, default=str) + "\n")


def load_params(path: str | os.PathLike, template: Any = None, what: str = "parameters") -> Any:
    """The tree stored at `path`, as nested dicts of arrays, or in the structure of `template`.

    Raises:
        ValueError: no such file, or it cannot be read (into `template`'s structure); the message
            names `what` the file should hold.
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"no {what} at {path}")
    try:
        stored = serialization.msgpack_restore(path.read_bytes())
    except Exception as err:  # msgpack raises assorted types for a damaged file
        raise ValueError(f"{path} does not hold readable {what} "
                         f"({type(err).__name__}: {err})") from err
    return stored if template is None else load_params_into(template, stored)


def load_params_into(template: Any, stored: Any) -> Any:
    """`stored` (as `load_params` returns it) in the structure of `template`.

    Raises:
        ValueError: it does not fit `template` (other shapes or keys).
    """
    try:
        return serialization.from_state_dict(template, stored)
    except Exception as err:  # flax raises assorted types for a tree of another structure
        raise ValueError(f"stored tree does not fit ({type(err).__name__}: {err})") from err


def kept_params(path: str | os.PathLike | None, compute: Callable[[], Any], template: Any = None,
                what: str = "parameters", log: Callable[[str], None] = print) -> Any:
    """`compute()`'s tree, kept at `path`: read from there when the file exists (a resumed run,
    in `template`'s structure), else computed and written. With `path` None: computed only."""
    if path is not None and Path(path).exists():
        log(f"{what} read from {path}")
        return load_params(path, template, what)
    tree = compute()
    if path is not None:
        save_params(path, tree)
    return tree


def load_encoder_file(family_or_path: str | os.PathLike, shipped: Callable[[str], Path],
                      method: str, title: str, input_layer: str) -> tuple[Path, Any, int]:
    """A pretrained formula encoder: the package's shipped one named `family_or_path` ("letter",
    "zone", "zone_overlap": `families.encoder_name`; at `shipped(name)`) or a file. Returns `(path, parameters, input width of the
    layer `input_layer`)` for the method's own shape check.

    Raises:
        ValueError: no such file, or no `title` encoder parameters in it.
    """
    name = str(family_or_path)
    is_shipped = Path(name).suffix == "" and os.sep not in name
    path = shipped(name) if is_shipped else Path(family_or_path)
    if not path.exists():
        how = (f"--env ID` with ID a world of the {name.removesuffix('_overlap')} family whose "
               "labels overlap (PointLTL1-v0 for zone, PandaLTLReach1Joints-v0 for arm)"
               if name.endswith("_overlap")
               else f"--family {name}`" if is_shipped else "--family FAMILY --out PATH`")
        raise ValueError(f"no pretrained {title} encoder at {path}; make one with "
                         f"`specrl-jax pretrain --method {method} {how}")
    stored = load_params(path, what=f"{title} encoder parameters")
    try:
        width = int(np.shape(stored["params"][input_layer]["kernel"])[0])
    except (KeyError, TypeError):
        raise ValueError(f"{path} holds no {title} encoder parameters") from None
    return path, stored, width


def read_meta(path: str | os.PathLike) -> dict[str, Any]:
    """The JSON written beside `path` by `save_params` ({} without one)."""
    meta = Path(path).with_suffix(".json")
    return json.loads(meta.read_text()) if meta.exists() else {}
