"""Async Gymnasium vector envs in a process where JAX already runs (used to deadlock at 0% CPU)."""

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import numpy as np

    def main():
        import jax.numpy as jnp
        jnp.ones(3).block_until_ready()  # JAX has started in this process
        import gymnasium
        import specrl_jax.gym  # noqa: F401
        envs = gymnasium.make_vec("LetterLTL0-v0", num_envs=2, vectorization_mode="async")
        obs, _ = envs.reset(seed=0)
        obs, *_ = envs.step(np.array([0, 1]))
        envs.close()
        print("async ok", obs.shape, flush=True)
        try:  # forking explicitly: the child refuses to run JAX instead of hanging
            gymnasium.make_vec("LetterLTL0-v0", num_envs=1, vectorization_mode="async",
                               vector_kwargs={"context": "fork"})
        except Exception as err:
            print("fork refused", type(err).__name__, flush=True)

    if __name__ == "__main__":
        main()
    """
)


def test_async_make_vec_after_jax_started(tmp_path):
    script = tmp_path / "run_async.py"
    script.write_text(SCRIPT)
    out = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=240,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "async ok (2, 7, 7, 13)" in out.stdout
    assert "fork refused" in out.stdout
    assert "this process was forked from one in which JAX had started" in out.stderr
