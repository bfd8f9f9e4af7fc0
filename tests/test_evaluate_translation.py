"""Translation evaluation: metrics, model specs, and a small run on real validation rows."""

from pathlib import Path

import numpy as np
import pytest

from simshear_gym.evaluate.metrics import mape, ssim
from simshear_gym.evaluate.translation import evaluate, parse_models, parse_readers
from simshear_gym.models.translator import save_generator
from simshear_gym.models.unet import UNetConfig, UNetGenerator


def test_mape_and_ssim_on_known_images():
    black, white = np.zeros((2, 32, 32), np.uint8), np.full((2, 32, 32), 255, np.uint8)
    np.testing.assert_allclose(mape(black, white), 1.0)
    np.testing.assert_allclose(mape(white, white), 0.0)
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (2, 32, 32), dtype=np.uint8)
    np.testing.assert_allclose(ssim(noise, noise), 1.0)
    assert (ssim(noise, 255 - noise) < 0).all()


def test_model_specs():
    models = parse_models(["a=x.pt", "b:edge=e.pt", "b:surface=s.pt"])
    assert models["a"]["edge"].name == "x.pt" and models["b"]["surface"].name == "s.pt"
    with pytest.raises(ValueError, match="NAME=PATH"):
        parse_models(["nopath"])
    with pytest.raises(ValueError, match="contact must be one of"):
        parse_models(["a:cylinder=x.pt"])
    assert parse_readers(["surface=r.pt"]) == {"surface": Path("r.pt")}
    with pytest.raises(ValueError, match="expected CONTACT=PATH"):
        parse_readers(["r.pt"])


@pytest.mark.data
@pytest.mark.slow
def test_small_evaluation_on_real_rows(data_root, tmp_path):
    generator = UNetGenerator(UNetConfig(image_size_px=128, base_channels=4, max_channels=8)).eval()
    save_generator(tmp_path / "g.pt", generator)
    from simshear_gym.models.zoo import posenet_weights

    reader = posenet_weights("surface")
    results, reader_floor, stacks = evaluate(
        data_root, {"tiny": {"surface": tmp_path / "g.pt", "edge": tmp_path / "g.pt"}}, rows=4, workers=1,
        readers={"surface": reader})
    assert set(results) == {"surface_shear", "surface_tap", "edge_shear", "edge_tap"}
    for methods in results.values():
        assert set(methods) == {"nearest-label retrieval", "tiny", "tiny (published sim input)"}
        for figures in methods.values():
            assert 0.0 <= figures["mape"] <= 1.0 and -1.0 <= figures["ssim"] <= 1.0
        # an untrained generator is far worse than retrieving the nearest real training image
        assert methods["tiny"]["mape"] > methods["nearest-label retrieval"]["mape"]
    assert stacks["edge_tap"]["real"].shape == (4, 128, 128)
    # the reader reads the real images' depth far better than an untrained generator's images
    assert set(reader_floor) == {"surface_shear", "surface_tap"}
    for set_name, floor in reader_floor.items():
        assert set(floor) == {"z_mm", "rx_deg", "ry_deg", "shear_x_mm", "shear_y_mm", "shear_rz_deg"}
        assert results[set_name]["tiny"]["reader_mae"]["z_mm"] > floor["z_mm"]
    assert "reader_mae" not in results["edge_tap"]["tiny"]
