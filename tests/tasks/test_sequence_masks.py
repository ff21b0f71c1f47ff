"""Reach-avoid pairs as proposition masks (GenZ-LTL's and GCRL-LTL's observed subgoal): the
inverse of the pair's symbol sets, on the zero-or-one alphabet and on every subset of the
propositions (moving zones, which may overlap)."""

import itertools

import jax.numpy as jnp
import numpy as np
import pytest

from specrl_jax.automata import all_subsets, zero_or_one
from specrl_jax.tasks.sources import proposition_masks, symbol_sets

PROPS = 4


@pytest.mark.parametrize("alphabet", [zero_or_one(PROPS), all_subsets(PROPS)],
                         ids=["zero_or_one", "all_subsets"])
def test_masks_invert_symbol_sets(alphabet):
    alphabet = jnp.asarray(alphabet, bool)
    masks = np.array(list(itertools.product([False, True], repeat=PROPS)))
    for empty in (False, True):
        sets = symbol_sets(jnp.asarray(masks), alphabet, jnp.full(len(masks), empty))
        np.testing.assert_array_equal(proposition_masks(sets, alphabet), masks)


def test_reach_one_colour_among_overlapping_labels():
    alphabet = jnp.asarray(all_subsets(PROPS), bool)
    reach = symbol_sets(jnp.array([True, False, False, False]), alphabet)
    assert int(reach.sum()) == 8  # every label holding proposition 0, with or without others
    np.testing.assert_array_equal(proposition_masks(reach, alphabet), [True, False, False, False])
    # a proposition that no label holds is in no mask
    partial = alphabet.at[:, 3].set(False)
    np.testing.assert_array_equal(proposition_masks(jnp.ones(len(alphabet), bool), partial),
                                  [True, True, True, False])
