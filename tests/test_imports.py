"""Importing the package, the Gymnasium bridge and listing env IDs load no physics."""

import json
import subprocess
import sys

import pytest

HEAVY = ("mujoco", "mujoco.mjx", "warp", "trimesh", "matplotlib", "spot")


def _loaded_after(code: str) -> list[str]:
    """The `HEAVY` modules in `sys.modules` after running `code` in a fresh interpreter."""
    probe = (f"{code}\nimport json, sys\n"
             f"print(json.dumps([m for m in {HEAVY + ('jax',)!r} if m in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_importing_the_package_loads_neither_jax_nor_physics():
    assert _loaded_after("import specrl_jax") == []


def test_gym_bridge_and_env_listing_load_no_physics():
    loaded = _loaded_after(
        "import specrl_jax.gym, gymnasium\n"
        "from specrl_jax.cli import main\n"
        "assert main(['envs']) == 0\n"
        "assert 'PandaLTLReach0Joints-v0' in gymnasium.registry"
    )
    assert not set(loaded) & set(HEAVY), loaded


def test_world_names_resolve_on_first_use():
    from specrl_jax.envs import arm, multi, zone
    from specrl_jax.envs.zone import config as zone_config

    assert zone.ZoneConfig is zone_config.ZoneConfig
    assert arm.ArmEnv.__name__ == "ArmEnv" and multi.MultiAutoReset.__name__ == "MultiAutoReset"
    with pytest.raises(AttributeError, match="has no attribute 'ZoneWorld'"):
        zone.ZoneWorld  # noqa: B018


def test_a_lazy_export_is_not_shadowed_by_its_module_of_the_same_name():
    """`envs.checked` is a function in the module `envs/checked.py`: importing the module binds
    its name on the package, which must not replace the exported function."""
    code = ("import importlib; from specrl_jax.envs import checked as first; "
            "importlib.import_module('specrl_jax.envs.checked'); "
            "from specrl_jax.envs import checked as second; "
            "assert callable(first) and second is first, (first, second)")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
