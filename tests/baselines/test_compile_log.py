"""Compilation beside other work: `in_background` hands back results and errors, and its thread
never holds an interrupted command."""

import threading

import pytest

from specrl_jax.baselines.compile_log import in_background


def test_in_background_hands_back_results_and_errors_from_a_daemon_thread():
    assert in_background(lambda a, b: a + b, 2, 3).result(timeout=10) == 5
    failed = in_background(lambda: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        failed.result(timeout=10)
    release, before = threading.Event(), set(threading.enumerate())
    in_background(release.wait)  # an interrupted command must not wait for this one
    started = set(threading.enumerate()) - before
    assert started and all(t.daemon for t in started)
    release.set()
