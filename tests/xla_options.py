"""Per-program XLA options for the few tests whose programs run far longer than they compile.

The suite compiles at LLVM optimisation level 0 with XLA:CPU's loop emitters (tests/conftest.py),
which halves compile times; a program that then runs for tens of seconds (hundreds of PPO updates,
a vmapped rejection sampler) is compiled with `OPTIMISED` instead:
`jax.jit(f, compiler_options=OPTIMISED)`.
"""

#: XLA's default optimisation level: the R-GCN's training runs twice as fast as at level 0, the
#: arm's layout sampler three times
OPTIMISED = {"xla_backend_optimization_level": 3}
