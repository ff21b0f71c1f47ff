"""Automata tests: a private disk cache for the whole session."""

import os

import pytest


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    old = os.environ.get("SPECRL_JAX_CACHE_DIR")
    os.environ["SPECRL_JAX_CACHE_DIR"] = str(tmp_path_factory.mktemp("automata_cache"))
    yield
    if old is None:
        del os.environ["SPECRL_JAX_CACHE_DIR"]
    else:
        os.environ["SPECRL_JAX_CACHE_DIR"] = old
