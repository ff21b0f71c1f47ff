"""Which shipped formula encoder a world reads, and the errors that name how to make one."""

import numpy as np
import pytest

from specrl_jax import families
from specrl_jax.baselines.rad import pretrain as rad_pretrain
from specrl_jax.envs.registry import make


def _none_or_one(props: int) -> np.ndarray:
    return np.concatenate([np.zeros((1, props), bool), np.eye(props, dtype=bool)])


def _every_subset(props: int) -> np.ndarray:
    return ((np.arange(2**props)[:, None] >> np.arange(props)) & 1).astype(bool)


def test_a_per_symbol_encoder_has_its_own_name_where_labels_overlap():
    assert families.encoder_name("zone", _none_or_one(4), per_symbol=True) == "zone"
    assert families.encoder_name("zone", _every_subset(4), per_symbol=True) == "zone_overlap"
    # an encoder of formulas over propositions reads any label set of the family
    assert families.encoder_name("zone", _every_subset(4), per_symbol=False) == "zone"
    assert families.encoder_name("letter", _none_or_one(12), per_symbol=True) == "letter"
    # the arm borrows Zone's encoder for grippers only; grippers+arm's every subset is its own
    assert families.encoder_name("arm", _none_or_one(4), per_symbol=True) == "zone"
    assert families.encoder_name("arm", _every_subset(8), per_symbol=True) == "arm_overlap"
    assert families.encoder_name("arm", _every_subset(8), per_symbol=False) == "zone"
    # one proposition: "nothing" and "it" are every subset and none-or-one alike
    assert families.encoder_name("zone", _every_subset(1), per_symbol=True) == "zone"


def test_moving_zones_read_the_overlap_encoder_and_the_plain_one_is_refused():
    moving = np.asarray(make("PointLTL1-v0")[0].alphabet)
    assert moving.shape == (16, 4)  # moving zones of different colours can overlap
    name = families.encoder_name("zone", moving, per_symbol=True)
    params = rad_pretrain.load_encoder(name, moving.shape[0])
    assert np.shape(params["params"]["embed"]["kernel"])[0] == 16 + (
        np.shape(rad_pretrain.load_encoder("zone", 5)["params"]["embed"]["kernel"])[0] - 5)
    with pytest.raises(ValueError, match="reads 5 symbols; the alphabet has 16"):
        rad_pretrain.load_encoder("zone", 16)


def test_a_missing_shipped_encoder_says_how_to_make_it():
    with pytest.raises(ValueError, match=r"pretrain --method rad --env ID` with ID a world of the "
                                         r"letter family whose labels overlap"):
        rad_pretrain.load_encoder("letter_overlap", 4096)
    with pytest.raises(ValueError, match=r"pretrain --method rad --family FAMILY --out PATH`"):
        rad_pretrain.load_encoder("/nonexistent/encoder.msgpack", 5)


def test_the_grippers_arm_alphabet_reads_its_shipped_encoder():
    world = make("PandaLTLReach1Joints-v0", table_contacts=False)[0]
    alphabet = np.asarray(world.alphabet)
    name = families.encoder_name("arm", alphabet, per_symbol=True)
    assert name == "arm_overlap"
    params = rad_pretrain.load_encoder(name, alphabet.shape[0])
    kernel = np.asarray(params["params"]["embed"]["kernel"])
    assert kernel.shape[0] >= alphabet.shape[0] == 256 and np.isfinite(kernel).all()
