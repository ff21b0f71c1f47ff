"""LTL specs as automata tensors: Spot translation, jittable stepping, reach-avoid subgoals."""

from specrl_jax.automata.stepping import (
    check_labels,
    epsilon_slot,
    has_epsilon,
    label_symbol,
    step,
    step_checked,
    step_in_batch,
    symbol_index,
    takes_epsilon,
)
from specrl_jax.automata.tensors import (
    CompiledSpec,
    Pairs,
    compile_spec,
    compile_suite,
    pairs,
    stack,
)
from specrl_jax.automata.translate import all_subsets, product, zero_or_one

__all__ = [
    "CompiledSpec",
    "Pairs",
    "all_subsets",
    "check_labels",
    "compile_spec",
    "compile_suite",
    "epsilon_slot",
    "has_epsilon",
    "label_symbol",
    "pairs",
    "product",
    "stack",
    "step",
    "step_checked",
    "step_in_batch",
    "symbol_index",
    "takes_epsilon",
    "zero_or_one",
]
