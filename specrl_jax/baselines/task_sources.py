"""What a method trains on in a world family: the family record's `task_sources` entry, either a
curriculum (a name of `specs.CURRICULA`) or the name of one of the original's formula samplers."""

from __future__ import annotations

from specrl_jax import families
from specrl_jax.specs import CURRICULA


def task_source(method: str, family: str) -> str | None:
    """The family's task source for `method`, None when it names none (or the family is unknown)."""
    if family not in families.list_families():
        return None
    return families.get(family).task_sources.get(method)


def curriculum_of(method: str, family: str) -> str | None:
    """The curriculum `method` trains on in `family`, None where its source is a sampler."""
    source = task_source(method, family)
    return source if source in CURRICULA else None


def families_with_curriculum(method: str) -> list[str]:
    return [f for f in families.list_families() if curriculum_of(method, f) is not None]
