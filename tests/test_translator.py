"""Translator models: shapes for every size, shear conditioning, a tiny training run, resume, weights files."""

import numpy as np
import pytest
import torch

from simshear_gym.models.translator import Translator, load_generator, save_generator
from simshear_gym.models.unet import PatchDiscriminator, UNetConfig, UNetGenerator
from simshear_gym.train.translator_config import TranslatorTrainConfig
from simshear_gym.train.translator_trainer import PairedTensors, TranslatorTrainer
from tests.clocks import StepClock


@pytest.mark.parametrize("size, depth", [(64, 6), (128, 7), (256, 8), (128, 5)])
@pytest.mark.parametrize("shear_dim, shear_decoder", [(0, False), (6, False), (6, True)])
def test_generator_shapes(size, depth, shear_dim, shear_decoder):
    generator = UNetGenerator(UNetConfig(image_size_px=size, depth=depth, base_channels=4, max_channels=16,
                                         shear_dim=shear_dim, shear_decoder=shear_decoder)).eval()
    sim = torch.rand(2, 1, size, size)
    out = generator(sim, torch.rand(2, 6) if shear_dim else None)
    assert out.shape == (2, 1, size, size) and 0.0 <= out.min() and out.max() <= 1.0
    logits = PatchDiscriminator()(sim, out)
    assert logits.shape[0] == 2 and logits.shape[1] == 1


def test_generator_rejects_wrong_inputs():
    generator = UNetGenerator(UNetConfig(image_size_px=64, depth=6, base_channels=4, max_channels=8))
    with pytest.raises(ValueError, match=r"sim must be \(B, 1, 64, 64\)"):
        generator(torch.rand(2, 1, 32, 32), torch.rand(2, 6))
    with pytest.raises(ValueError, match=r"shear must be \(B, 6\)"):
        generator(torch.rand(2, 1, 64, 64))
    with pytest.raises(ValueError, match="power of two"):
        UNetConfig(image_size_px=100)
    with pytest.raises(ValueError, match="shear_decoder needs shear_dim"):
        UNetConfig(shear_dim=0, shear_decoder=True)
    with pytest.raises(ValueError, match="needs template=True"):
        UNetConfig(template=False, flow_px=32)
    with pytest.raises(ValueError, match="flow_px must be a power of two from 4 to 64"):
        UNetConfig(image_size_px=128, depth=6, flow_px=128)


def test_warp_starts_at_rest_and_moves_the_template_by_the_field():
    torch.manual_seed(0)
    generator = UNetGenerator(UNetConfig(image_size_px=32, depth=5, base_channels=4, max_channels=16, flow_px=8))
    template = torch.rand(32, 32)
    generator.init_template(template)
    out = generator(torch.rand(2, 1, 32, 32), torch.rand(2, 6))
    assert torch.allclose(out, template.clamp(0.02, 0.98).expand_as(out), atol=1e-5)  # zero field, zero residual
    field = torch.zeros(1, 2, 8, 8)
    field[:, 0] = 3.0  # every output pixel samples the template 3 px to its right
    warped = generator._warped_template(field)[0, 0]
    logit = generator.output_logit[0, 0]
    assert torch.allclose(warped[:, :-3], logit[:, 3:], atol=1e-5)
    assert torch.allclose(warped[:, -3:], logit[:, -1:].expand(-1, 3), atol=1e-5)  # border padding


def test_cosine_schedule_decays_to_zero_over_the_run(tmp_path):
    config = tiny_config(lr=1e-3, lr_schedule="cosine", epochs=2)
    assert config.lr_at(0.0) == pytest.approx(1e-3) and config.lr_at(0.5) == pytest.approx(5e-4)
    assert config.lr_at(1.0) == pytest.approx(0.0, abs=1e-12) and config.lr_at(2.0) == pytest.approx(0.0, abs=1e-12)
    assert tiny_config(lr=1e-3).lr_at(0.9) == 1e-3  # constant
    with pytest.raises(ValueError, match="lr_schedule must be one of"):
        tiny_config(lr_schedule="step")
    trainer = TranslatorTrainer(config, tmp_path / "run", toy_pairs())
    trainer.fit(progress=False)
    last_lr = trainer.opt_g.param_groups[0]["lr"]
    assert 0.0 < last_lr < 0.1 * config.lr  # the last step ran near the end of the schedule


def toy_pairs(n=48, size=32, seed=0):
    """Real image = a bright square whose position follows the shear: learnable only with the shear."""
    rng = np.random.default_rng(seed)
    shear = rng.uniform(-5, 5, (n, 6)).astype(np.float32)
    sim = np.zeros((n, size, size), np.uint8)
    sim[:, 12:20, 12:20] = 40
    real = np.zeros((n, size, size), np.uint8)
    for i, (dx, dy) in enumerate(shear[:, :2]):
        x, y = int(12 + dx), int(12 + dy)
        real[i, y:y + 8, x:x + 8] = 255
    return PairedTensors(torch.from_numpy(sim), torch.from_numpy(shear), torch.from_numpy(real))


def tiny_config(**overrides):
    settings = dict(paired_dirs=("toy",), image_size_px=32, base_channels=4, max_channels=16, epochs=3,
                    batch_size=8, lr=2e-3, holdout=0.2, threads=1)
    settings.update(overrides)
    return TranslatorTrainConfig(**settings)


@pytest.mark.parametrize("gan_weight", [0.0, 1.0])
def test_tiny_training_run_end_to_end(tmp_path, gan_weight):
    trainer = TranslatorTrainer(tiny_config(gan_weight=gan_weight), tmp_path / "run", toy_pairs())
    before = trainer.holdout_l1()
    summary = trainer.fit(progress=False)
    assert summary["epochs"] == 3 and summary["best_holdout_l1"] < before
    for name in ("config.json", "history.json", "checkpoint.pt", "best.pt"):
        assert (tmp_path / "run" / name).is_file()
    assert any((tmp_path / "run" / "tb").iterdir())
    translator = Translator.load(tmp_path / "run" / "best.pt")
    out = translator(np.zeros((3, 32, 32), np.uint8), np.zeros((3, 6), np.float32))
    assert out.shape == (3, 32, 32) and out.dtype == np.uint8


def test_density_loss_asks_for_the_marker_brightness_where_their_places_are_uncertain(tmp_path):
    """Real images: a grid of 2 px markers at a 4 px pitch, shifted by a random phase whatever the input (markers
    of a sheared contact, where the generator cannot know their exact places). Every pixel is bright a quarter of
    the time, so L1 alone draws black (its median); the density term asks for the grid's mean brightness."""
    from torch.nn import functional as F

    rng = np.random.default_rng(0)
    n, size = 96, 32
    real = np.zeros((n, size, size), np.uint8)
    for i, (dx, dy) in enumerate(rng.integers(0, 4, (n, 2))):
        for y in range(dy, size, 4):
            for x in range(dx, size, 4):
                real[i, y:y + 2, x:x + 2] = 255
    pairs = PairedTensors(torch.zeros(n, size, size, dtype=torch.uint8), torch.zeros(n, 6), torch.from_numpy(real))
    brightness = {}
    for density_weight in (0.0, 300.0):
        trainer = TranslatorTrainer(tiny_config(arch="pix2pix", epochs=8, density_weight=density_weight),
                                    tmp_path / f"run{density_weight}", pairs)
        trainer.fit(progress=False)
        out = Translator(trainer.generator)(np.zeros((1, size, size), np.uint8)).astype(float) / 255
        brightness[density_weight] = float(F.avg_pool2d(torch.from_numpy(out)[None], 8).mean())
    assert brightness[0.0] < 0.1  # L1's median: black, where the real grid has a mean brightness of 0.25
    assert abs(brightness[300.0] - 0.25) < 0.1
    with pytest.raises(ValueError, match="loss weights >= 0"):
        tiny_config(density_weight=-1.0)


@pytest.mark.parametrize("shear_decoder, flow_px", [(False, 0), (True, 0), (False, 8)])
def test_shear_changes_trained_shpix2pix_output(tmp_path, shear_decoder, flow_px):
    """On data where the real image follows the shear, a trained shPix2pix moves its output with the shear."""
    trainer = TranslatorTrainer(tiny_config(epochs=10, shear_decoder=shear_decoder, flow_px=flow_px),
                                tmp_path / "run", toy_pairs(n=192))
    trainer.fit(progress=False)
    translator = Translator(trainer.generator)
    sim = toy_pairs(n=2).sim.numpy()
    left = translator(sim, np.array([[-4.0, 0, 0, 0, 0, 0]] * 2, np.float32)).astype(float)
    right = translator(sim, np.array([[4.0, 0, 0, 0, 0, 0]] * 2, np.float32)).astype(float)
    columns = np.arange(32)
    centre_left = (left.sum(axis=1) * columns).sum(axis=1) / left.sum(axis=(1, 2))
    centre_right = (right.sum(axis=1) * columns).sum(axis=1) / right.sum(axis=(1, 2))
    assert (centre_right - centre_left > 2.0).all()  # the square moved right with +x shear


def test_resume_continues_where_it_stopped(tmp_path):
    pairs = toy_pairs()
    straight = TranslatorTrainer(tiny_config(epochs=4), tmp_path / "straight", pairs)
    straight.fit(progress=False)
    first = TranslatorTrainer(tiny_config(epochs=2), tmp_path / "split", pairs)
    first.fit(progress=False)
    second = TranslatorTrainer(tiny_config(epochs=4), tmp_path / "split", pairs)
    assert second.resume() and second.epoch == 2
    second.fit(progress=False)
    assert second.epoch == 4 and len(second.history) == 4
    for key, value in straight.generator.state_dict().items():
        torch.testing.assert_close(second.generator.state_dict()[key], value, rtol=1e-4, atol=1e-5)


def test_resume_refuses_other_settings(tmp_path):
    TranslatorTrainer(tiny_config(epochs=1), tmp_path / "run", toy_pairs()).fit(progress=False)
    other = TranslatorTrainer(tiny_config(lr=1e-4), tmp_path / "run", toy_pairs())
    with pytest.raises(ValueError, match=r"other settings \(\['lr'\]\)"):
        other.resume()


def test_time_budget_stops_and_checkpoints(tmp_path):
    trainer = TranslatorTrainer(tiny_config(epochs=50, max_minutes=0.5 / 60), tmp_path / "run", toy_pairs())
    trainer.clock = clock = StepClock()  # 1/16 s a step: the budget ends in the 9th step
    step = trainer.train_batch
    trainer.train_batch = lambda index: (clock.advance(1 / 16), step(index))[1]
    summary = trainer.fit(progress=False)
    assert summary["stopped_by"] == "time budget" and summary["steps"] == 9
    assert (tmp_path / "run" / "checkpoint.pt").is_file()


def test_fp16_weights_round_trip(tmp_path):
    generator = UNetGenerator(UNetConfig(image_size_px=64, depth=6, base_channels=4, max_channels=8)).eval()
    save_generator(tmp_path / "g.pt", generator, card={"note": "x"})
    loaded, card = load_generator(tmp_path / "g.pt")
    assert card == {"note": "x"}
    sim, shear = torch.rand(2, 1, 64, 64), torch.rand(2, 6)
    torch.testing.assert_close(loaded(sim, shear), generator(sim, shear), atol=5e-3, rtol=0)
    (tmp_path / "bad.pt").write_bytes(b"nonsense")
    with pytest.raises(Exception):
        load_generator(tmp_path / "bad.pt")
    with pytest.raises(FileNotFoundError, match="not found"):
        load_generator(tmp_path / "missing.pt")


@pytest.mark.parametrize("shear_dim, shear_decoder, decoder_scale, flow_px", [
    (0, False, 1.0, 0), (6, False, 1.0, 0), (6, True, 0.5, 0), (6, False, 0.5, 16)])
def test_fast_translator_matches_the_eager_generator(shear_dim, shear_decoder, decoder_scale, flow_px):
    torch.manual_seed(0)
    generator = UNetGenerator(UNetConfig(image_size_px=64, depth=6, base_channels=4, max_channels=16,
                                         shear_dim=shear_dim, shear_decoder=shear_decoder,
                                         decoder_scale=decoder_scale, flow_px=flow_px))
    for module in generator.modules():  # non-trivial batch-norm statistics, so folding them is tested
        if isinstance(module, torch.nn.BatchNorm2d):
            module.running_mean.uniform_(-0.5, 0.5)
            module.running_var.uniform_(0.5, 2.0)
    if flow_px:  # a non-zero field and template, so the warp is tested
        generator.output_logit.data.uniform_(-3.0, 3.0)
        generator.flow.weight.data.normal_(0.0, 0.5)
    rng = np.random.default_rng(0)
    sim = rng.integers(0, 60, (3, 64, 64), dtype=np.uint8)
    shear = rng.uniform(-5, 5, (3, 6)).astype(np.float32)
    fast, eager = Translator(generator), Translator(generator, fast=False)
    assert np.abs(fast(sim, shear).astype(int) - eager(sim, shear).astype(int)).max() <= 1
    assert np.array_equal(fast(sim[:1], shear[:1]), fast(sim, shear)[:1])  # batch size is not baked in
    with pytest.raises(ValueError, match="64x64 px"):
        fast(np.zeros((1, 32, 32), np.uint8), shear[:1])
    if shear_dim:
        with pytest.raises(ValueError, match=r"shear_sensor must be \(B, 6\)"):
            fast(sim, shear[:2])


@pytest.mark.parametrize("in_channels, out_channels, size_px, bias", [(8, 8, 1, False), (16, 4, 4, False),
                                                                       (6, 1, 16, True), (4, 3, 5, True)])
def test_column_transposed_conv_equals_the_transposed_convolution(in_channels, out_channels, size_px, bias):
    from simshear_gym.models.unet import _ColumnTransposedConv

    torch.manual_seed(0)
    upsample = torch.nn.ConvTranspose2d(in_channels, out_channels, 4, stride=2, padding=1, bias=bias)
    x = torch.randn(3, in_channels, size_px, size_px)
    with torch.no_grad():
        expected, got = upsample(x), _ColumnTransposedConv(upsample)(x)
    assert got.shape == expected.shape == (3, out_channels, 2 * size_px, 2 * size_px)
    assert torch.allclose(got, expected, atol=1e-5)
    with pytest.raises(ValueError, match="plain stride-2"):
        _ColumnTransposedConv(torch.nn.ConvTranspose2d(4, 4, 3, stride=1, padding=1))


def test_pose_consistency_trains_the_generator_through_a_frozen_gdnn(tmp_path):
    """Pose loss alone (L1 weight 0): the generator learns to show the frozen reader the rows' labels."""
    from simshear_gym.models.gdnn import GDNN, GDNNConfig
    from simshear_gym.models.posenet_io import save_posenet
    from simshear_gym.train.pose_consistency import PoseConsistency

    torch.manual_seed(0)
    reader = GDNN(GDNNConfig(image_size_px=16, conv_channels=(4,), conv_kernels=(3,), dense=(8,))).eval()
    save_posenet(tmp_path / "reader.pt", reader)
    pose = PoseConsistency(tmp_path / "reader.pt")
    pairs = toy_pairs(n=96)
    with torch.no_grad():  # labels the reader gives the real images: reachable by a generator that draws them
        labels = reader(torch.nn.functional.interpolate(pairs.real.unsqueeze(1).float() / 255, size=16,
                                                        mode="area"))[0]
    pairs = PairedTensors(pairs.sim, pairs.shear, pairs.real, labels)
    config = tiny_config(epochs=8, l1_weight=0.0, pose_weight=1.0, pose_net=str(tmp_path / "reader.pt"))
    trainer = TranslatorTrainer(config, tmp_path / "run", pairs, pose)
    before_weights = {k: v.clone() for k, v in pose.gdnn.state_dict().items()}

    def pose_loss():
        sim, shear, _, encoded = pairs.batch(np.arange(len(pairs)))
        with torch.no_grad():
            return pose.loss(trainer.generator(sim, shear), encoded).item()

    before = pose_loss()
    trainer.fit(progress=False)
    assert pose_loss() < 0.5 * before
    for key, value in pose.gdnn.state_dict().items():
        torch.testing.assert_close(value, before_weights[key])  # the reader stays frozen
    assert pose.encoded_labels({"pose_3": [2.0, 5.5], "pose_4": [0.0, 15.0], "pose_5": [0.0, -15.0],
                                "shear_sensor_x_mm": [0.0, 7.5], "shear_sensor_y_mm": [0.0, 0.0],
                                "shear_sensor_rz_deg": [0.0, 0.0]}).tolist() == [
        [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [1.0, 1.0, -1.0, 1.0, 0.0, 0.0]]


def test_pose_consistency_settings_must_agree(tmp_path):
    with pytest.raises(ValueError, match="pose_weight 1.0 must be >= 0, and above 0 exactly when a pose_net"):
        tiny_config(pose_weight=1.0)
    with pytest.raises(ValueError, match="needs its PoseConsistency and pairs loaded with it"):
        TranslatorTrainer(tiny_config(pose_weight=1.0, pose_net="reader.pt"), tmp_path / "run", toy_pairs())
    from simshear_gym.train.pose_consistency import PoseConsistency

    with pytest.raises(FileNotFoundError, match="missing.pt not found"):
        PoseConsistency(tmp_path / "missing.pt")


def test_pose_consistency_compares_only_the_chosen_variables(tmp_path):
    from simshear_gym.models.gdnn import GDNN, GDNNConfig
    from simshear_gym.models.posenet_io import save_posenet
    from simshear_gym.train.pose_consistency import PoseConsistency

    reader = GDNN(GDNNConfig(image_size_px=16, conv_channels=(4,), conv_kernels=(3,), dense=(8,),
                             variables="edge")).eval()
    save_posenet(tmp_path / "reader.pt", reader)
    images = torch.rand(3, 1, 32, 32)
    with torch.no_grad():
        mean = reader(torch.nn.functional.interpolate(images, size=16, mode="area"))[0]
    wrong_shear = mean.clone()
    wrong_shear[:, 4:] += 1.0  # encoded: y, z, sin, cos of the edge angle, then shear x, y, Rz
    pose_only = PoseConsistency(tmp_path / "reader.pt", ("y_mm", "z_mm", "edge_angle_deg"))
    assert pose_only.columns.tolist() == [0, 1, 2, 3]
    with torch.no_grad():
        assert pose_only.loss(images, wrong_shear).item() == pytest.approx(0.0, abs=1e-10)
        assert PoseConsistency(tmp_path / "reader.pt").loss(images, wrong_shear).item() == pytest.approx(3 / 7)
    with pytest.raises(ValueError, match=r"variables \['rx_deg'\] are not outputs"):
        PoseConsistency(tmp_path / "reader.pt", ("rx_deg",))


def test_a_distilled_student_learns_the_teachers_images_not_the_real_ones(tmp_path):
    """The teacher draws the square where the shear says; the 'real' images are blank. The student trained with
    --teacher learns the teacher's squares, so its output moves with the shear as the teacher's does."""
    from simshear_gym.train.translator_trainer import teacher_targets

    teacher_run = TranslatorTrainer(tiny_config(epochs=10), tmp_path / "teacher", toy_pairs(n=192))
    teacher_run.fit(progress=False)
    save_generator(tmp_path / "teacher.pt", teacher_run.generator.eval())
    blank = toy_pairs(n=192)
    blank = PairedTensors(blank.sim, blank.shear, torch.zeros_like(blank.real))
    targets = teacher_targets(blank, tmp_path / "teacher.pt", "shpix2pix")
    teacher = Translator.load(tmp_path / "teacher.pt")
    np.testing.assert_array_equal(targets.real.numpy()[:5], teacher(blank.sim.numpy()[:5], blank.shear.numpy()[:5]))
    student_run = TranslatorTrainer(tiny_config(epochs=10, base_channels=2, max_channels=8,
                                                teacher=str(tmp_path / "teacher.pt")), tmp_path / "student", blank)
    student_run.fit(progress=False)
    student = Translator(student_run.generator)
    sim = toy_pairs(n=2).sim.numpy()
    shear = np.array([[-4.0, 0, 0, 0, 0, 0], [4.0, 0, 0, 0, 0, 0]], np.float32)
    out = student(sim, shear).astype(float)
    assert out.mean() > 5  # not the blank 'real' images
    centres = (out.sum(axis=1) * np.arange(32)).sum(axis=1) / out.sum(axis=(1, 2))
    assert centres[1] - centres[0] > 2.0  # the square moved right with +x shear, as the teacher's
    with pytest.raises(ValueError, match="teacher .* is a shpix2pix of 32 px; the student is a pix2pix"):
        teacher_targets(blank, tmp_path / "teacher.pt", "pix2pix")
    with pytest.raises(ValueError, match="L1 alone"):
        tiny_config(teacher="t.pt", density_weight=1.0)
    with pytest.raises(FileNotFoundError, match="teacher translator .*missing.pt not found"):
        teacher_targets(blank, tmp_path / "missing.pt", "shpix2pix")


def test_a_fine_tuning_run_starts_from_a_translators_weights(tmp_path):
    """init_weights: the generator starts as the given translator (its holdout L1 before training is that
    translator's), read relative to files_root; another architecture is refused naming the file and the fields."""
    pairs = toy_pairs()
    first = TranslatorTrainer(tiny_config(epochs=4), tmp_path / "first", pairs)
    first.fit(progress=False)
    save_generator(tmp_path / "start.pt", first.generator.eval())
    tuned = TranslatorTrainer(tiny_config(epochs=1, init_weights="start.pt"), tmp_path / "tuned", pairs,
                              files_root=tmp_path)
    fresh = TranslatorTrainer(tiny_config(epochs=1), tmp_path / "fresh", pairs)
    start = Translator.load(tmp_path / "start.pt").generator.state_dict()
    for key, value in tuned.generator.state_dict().items():
        torch.testing.assert_close(value, start[key].to(value.dtype))
    assert tuned.holdout_l1() < fresh.holdout_l1()
    assert tuned.holdout_l1() == pytest.approx(first.holdout_l1(), abs=2e-3)  # the fp16-stored weights
    with pytest.raises(ValueError, match=r"init_weights .*start.pt: its generator is not the architecture .*"
                                         r"'base_channels': \(8, 4\)"):
        TranslatorTrainer(tiny_config(base_channels=8, init_weights=str(tmp_path / "start.pt")),
                          tmp_path / "wide", pairs)
    with pytest.raises(ValueError, match="give init_weights or teacher, not both"):
        tiny_config(init_weights="a.pt", teacher="b.pt")
