"""The committed reference parameters still load from the store and act: seed 1 of
LetterLTL0-v0/genz on a handful of IND episodes (the committed result is 1.00 success)."""

import jax
import pytest

from specrl_jax.baselines import experiment
from specrl_jax.benchmark import grid
from specrl_jax.benchmark.store import Store


@pytest.mark.slow  # compiling the evaluator: about 30 s on a quiet 2-core CPU
def test_committed_parameters_load_and_evaluate():
    store, cell = Store(), grid.cell("LetterLTL0-v0/genz")
    params = store.load_params(cell)
    assert jax.tree.leaves(params)[0].shape[0] == 1  # one seed, given a seed axis
    (result,) = experiment.evaluate(cell.method, cell.env_id, params, ["letter/finite/ind"], 2,
                                    log=lambda line: None)
    metrics = result.suite_metrics()
    assert result.result.seeds == (1,)
    stored = store.read(cell)["suites"]["letter/finite/ind"]["per_seed"]["eta_s"][0]
    assert metrics["eta_s_mean"] >= 0.8 and min(stored) >= 0.95
