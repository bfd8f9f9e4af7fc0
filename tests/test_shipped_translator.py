"""The shipped translator weights load, are small, and reproduce their stored check figure on real rows."""

import pytest

from simshear_gym.data.paths import real_set_dir
from simshear_gym.data.tactile_set import read_set
from simshear_gym.evaluate.metrics import mape
from simshear_gym.models.translator import Translator
from simshear_gym.models.zoo import shipped_translators
from simshear_gym.sim.replay import render_poses
from simshear_gym.sim.shear import ShearTrackerConfig, replay_shear

SHIPPED = shipped_translators()


def test_shpix2pix_is_shipped_for_both_contact_types():
    assert {("shpix2pix", "surface"), ("shpix2pix", "edge")} <= set(SHIPPED)
    for path in set(SHIPPED.values()):
        assert path.stat().st_size < 10 * 2**20, f"{path.name} is over 10 MiB"
        assert path.with_suffix(".md").is_file(), f"{path.name} has no model card"


@pytest.mark.data
@pytest.mark.parametrize("arch, contact", sorted(SHIPPED))
def test_shipped_weights_reproduce_stored_check(data_root, arch, contact):
    translator = Translator.load(SHIPPED[(arch, contact)])
    check = translator.card["check"]
    val = read_set(real_set_dir(data_root, contact, check["kind"], "val"))
    rows = slice(0, check["rows"])
    poses, moves = val.poses()[rows], val.moves()[rows]
    generated = translator(render_poses(contact, poses), replay_shear(poses, moves, ShearTrackerConfig()))
    assert abs(float(mape(generated, val.load_images()[rows]).mean()) - check["mape"]) < 2e-3
