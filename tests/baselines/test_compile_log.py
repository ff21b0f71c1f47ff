"""Compilation beside other work: `in_background` hands back results and errors, runs under the
caller's per-thread JAX settings, and holds the process until it ends."""

import os
import subprocess
import sys
import threading

import jax
import jax.numpy as jnp
import pytest

from specrl_jax.baselines.compile_log import in_background


def test_in_background_hands_back_results_and_errors():
    assert in_background(lambda a, b: a + b, 2, 3).result(timeout=10) == 5
    failed = in_background(lambda: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        failed.result(timeout=10)
    interrupted = in_background(lambda: (_ for _ in ()).throw(KeyboardInterrupt))
    with pytest.raises(KeyboardInterrupt):
        interrupted.result(timeout=10)


def test_in_background_compiles_under_the_callers_settings():
    def compiled_dtype():
        return jax.jit(lambda x: x * 2).lower(jnp.arange(3)).compile()(jnp.arange(3)).dtype

    with jax.enable_x64(True):
        assert in_background(compiled_dtype).result(timeout=60) == jnp.int64
    assert in_background(compiled_dtype).result(timeout=60) == jnp.int32


def test_a_process_ending_during_a_background_compilation_waits_for_it(tmp_path):
    release = threading.Event()
    in_background(release.wait)
    assert any(not t.daemon and t.is_alive() for t in threading.enumerate()
               if t is not threading.current_thread())
    release.set()
    script = ("import threading, time, jax, jax.numpy as jnp\n"
              "from specrl_jax.baselines.compile_log import in_background\n"
              "def long(x):\n"
              "    for i in range(400):\n"
              "        x = jnp.sin(x @ x.T + i) * jnp.cos(x)\n"
              "        x = jax.lax.cond(x.sum() > 0, lambda y: y * 2, lambda y: y - 1, x)\n"
              "    return x\n"
              "lowered = threading.Event()\n"
              "def work():\n"
              "    program = jax.jit(long).lower(jax.ShapeDtypeStruct((64, 64), jnp.float32))\n"
              "    lowered.set()\n"
              "    program.compile()\n"
              "    print('compiled', flush=True)\n"
              "in_background(work)\n"
              "lowered.wait()\n"
              "time.sleep(0.2)\n"
              "print('leaving', flush=True)\n")  # leaving mid-compilation: a daemon thread aborts
    # XLA's default optimisation and a fresh cache: the compilation outlasts the main thread
    env = {**{k: v for k, v in os.environ.items() if k != "XLA_FLAGS"},
           "SPECRL_JAX_CACHE_DIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", script], check=False, capture_output=True,
                          text=True, timeout=300, env=env)
    assert done.returncode == 0 and done.stdout == "leaving\ncompiled\n", done.stderr[-2000:]
