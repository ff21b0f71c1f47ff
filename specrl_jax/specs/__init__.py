"""Specifications: evaluation suites, seeded formula samplers, jittable training sequences.

Satisfiability: every sampler here is satisfiable under the "at most one proposition" alphabet
by construction (each module states its rule); `is_satisfiable` checks any formula with Spot,
and the tests run it over hundreds of samples and every suite.
"""

from specrl_jax.specs.curricula import (
    CURRICULA,
    Curriculum,
    CurriculumSampler,
    CurriculumState,
    Stage,
    curriculum,
    with_stay,
)
from specrl_jax.specs.formulas import (
    ltl2action_sampler,
    reach_avoid_formula,
    reach_only_formula,
    sample_eventually,
    sample_reach_avoid,
    sample_reach_only,
    sample_until,
    sequence_to_formula,
)
from specrl_jax.specs.satisfiable import alphabet_constraint, is_satisfiable, parse
from specrl_jax.specs.sequences import (
    GenZTasks,
    ReachAvoidSequence,
    all_reach_avoid_tasks,
    all_reach_tasks,
    genz_tasks,
    sample_genz_subgoal,
    sample_reach_stay,
    sample_task,
    twin_matrix,
)
from specrl_jax.specs.sequences import sample_reach_avoid as sample_reach_avoid_sequence
from specrl_jax.specs.suites import (
    SuiteInfo,
    complexity_formulas,
    list_suites,
    register_suite,
    suite,
    suite_info,
    suite_version,
    unregister_suite,
)

__all__ = [
    "CURRICULA",
    "Curriculum",
    "CurriculumSampler",
    "CurriculumState",
    "GenZTasks",
    "ReachAvoidSequence",
    "Stage",
    "SuiteInfo",
    "all_reach_avoid_tasks",
    "all_reach_tasks",
    "alphabet_constraint",
    "complexity_formulas",
    "curriculum",
    "genz_tasks",
    "is_satisfiable",
    "list_suites",
    "ltl2action_sampler",
    "parse",
    "reach_avoid_formula",
    "reach_only_formula",
    "register_suite",
    "sample_eventually",
    "sample_genz_subgoal",
    "sample_reach_avoid",
    "sample_reach_avoid_sequence",
    "sample_reach_only",
    "sample_reach_stay",
    "sample_task",
    "sample_until",
    "sequence_to_formula",
    "suite",
    "suite_info",
    "suite_version",
    "twin_matrix",
    "unregister_suite",
    "with_stay",
]
