"""The shared epoch loop (train/loop.py) on a tiny fake trainer, and the training commands' flags (train/flags.py)."""

import argparse
import json
import subprocess
import sys
from dataclasses import asdict, dataclass

import numpy as np
import pytest
import torch

from simshear_gym.train import flags, posenet, posenet_config, rl, translator, translator_config
from simshear_gym.train.loop import EpochTrainer
from simshear_gym.train.runs import scheduled_lr
from tests.clocks import StepClock


@dataclass(frozen=True)
class FakeConfig:
    epochs: int = 3
    max_minutes: float | None = None
    cap_minutes: float | None = None
    patience_epochs: int = 10
    lr: float = 0.1
    lr_schedule: str = "constant"
    threads: int = 1
    seed: int = 0
    rows: int = 8
    batch_size: int = 2
    reference_batch: int = 2
    lr_scaling: str = "none"
    warmup_epochs: float = 0.0
    holdout_script: tuple[float, ...] = ()  # the holdout metric of each epoch; () -> measured on the weight
    step_s: float = 0.0  # the training time a step takes on the trainer's clock


class FakeTrainer(EpochTrainer):
    """Fits one weight to noisy targets around 1 drawn from its own generator; holdout: (weight - 1)^2."""

    metric = "loss"

    def __init__(self, config: FakeConfig, run_dir) -> None:
        super().__init__(config, run_dir)
        self.clock = StepClock()
        self.weight = torch.nn.Parameter(torch.zeros(()))
        self.optimiser = torch.optim.SGD([self.weight], lr=config.lr, momentum=0.5)
        self.rng = np.random.default_rng(config.seed)
        self.lrs_seen: list[float] = []
        self.batch_sizes_seen: list[int] = []
        self.best_cards: list[dict] = []

    def epoch_batches(self):
        order = self.rng.permutation(self.config.rows)
        size = self.config.batch_size
        return [order[i:i + size] for i in range(0, len(order), size)]

    def optimisers(self):
        return [self.optimiser]

    def train_mode(self):
        pass

    def train_batch(self, index):
        self.lrs_seen.append(self.optimiser.param_groups[0]["lr"])
        self.batch_sizes_seen.append(len(index))
        self.clock.advance(self.config.step_s)
        loss = (self.weight - float(self.rng.normal(1.0, 0.2))) ** 2
        self.optimiser.zero_grad()
        loss.backward()
        self.optimiser.step()
        return {"loss": loss.item(), "weight": self.weight.item()}

    def holdout_metric(self):
        if self.config.holdout_script:
            return self.config.holdout_script[len(self.history)]
        return float((self.weight.detach() - 1.0) ** 2)

    def save_best(self, path, card):
        self.best_cards.append(card)
        path.write_text(json.dumps(card))

    def trainer_state(self):
        return {"weight": self.weight.detach().clone(), "optimiser": self.optimiser.state_dict(),
                "rng": self.rng.bit_generator.state}

    def load_trainer_state(self, state):
        with torch.no_grad():
            self.weight.copy_(state["weight"])
        self.optimiser.load_state_dict(state["optimiser"])
        self.rng.bit_generator.state = state["rng"]


def without_times(history):
    return [{k: v for k, v in record.items() if k != "elapsed_s"} for record in history]


def test_stops_at_the_epoch_budget_and_writes_the_run_directory(tmp_path):
    run_dir = tmp_path / "run"
    trainer = FakeTrainer(FakeConfig(epochs=3), run_dir)
    summary = trainer.fit(progress=False)
    assert summary["epochs"] == 3 and summary["steps"] == 12 and summary["stopped_by"] == "epochs"
    assert set(summary) == {"epochs", "steps", "elapsed_s", "best_holdout_loss", "stopped_by"}
    as_json = json.loads(json.dumps(asdict(trainer.config)))
    assert json.loads((run_dir / "config.json").read_text()) == as_json
    saved = json.loads((run_dir / "history.json").read_text())
    assert saved["config"] == as_json
    assert [list(record) for record in saved["epochs"]] == [
        ["epoch", "partial_epoch", "step", "elapsed_s", "train_loss", "holdout_loss"]] * 3
    assert [(r["epoch"], r["step"], r["partial_epoch"]) for r in saved["epochs"]] == [
        (1, 4, False), (2, 8, False), (3, 12, False)]
    checkpoint = torch.load(run_dir / "checkpoint.pt", weights_only=False)
    assert {"config", "epoch", "step", "best_holdout_loss", "epochs_since_best", "elapsed_s", "history", "weight",
            "optimiser", "rng"} == set(checkpoint)
    assert checkpoint["epoch"] == 3 and checkpoint["history"] == saved["epochs"]
    assert any((run_dir / "tb").iterdir())
    assert trainer.fit(progress=False)["epochs"] == 3  # nothing left to do


def test_best_is_the_lowest_holdout_metric_and_patience_stops_early(tmp_path):
    script = (3.0, 2.0, 2.5, 1.5, 1.6, 1.7, 1.8, 0.1)
    trainer = FakeTrainer(FakeConfig(epochs=8, patience_epochs=3, holdout_script=script), tmp_path / "run")
    summary = trainer.fit(progress=False)
    assert summary["stopped_by"] == "early stopping" and summary["epochs"] == 7  # 3 epochs after the best (4th)
    assert summary["best_holdout_loss"] == 1.5 and trainer.epochs_since_best == 3
    assert [card["epoch"] for card in trainer.best_cards] == [1, 2, 4]  # saved only when the metric improved
    best = json.loads((tmp_path / "run" / "best.pt").read_text())
    assert best["holdout_loss"] == 1.5 and best["epoch"] == 4 and best["elapsed_s"] >= 0
    assert [r["holdout_loss"] for r in trainer.history] == list(script[:7])


def test_time_budget_stops_inside_an_epoch_and_checkpoints_it(tmp_path):
    config = FakeConfig(epochs=1000, max_minutes=0.5 / 60, step_s=1 / 16)  # 4 steps an epoch
    trainer = FakeTrainer(config, tmp_path / "run")
    summary = trainer.fit(progress=False)
    assert summary["stopped_by"] == "time budget" and (summary["epochs"], summary["steps"]) == (2, 9)
    assert trainer.history[-1]["partial_epoch"] and not any(r["partial_epoch"] for r in trainer.history[:-1])
    assert summary["epochs"] == len(trainer.history) - 1  # the partial epoch does not count
    assert torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)["step"] == summary["steps"]


def test_wall_clock_cap_stops_at_the_last_finished_epoch_and_leaves_the_schedule_on_the_steps(tmp_path):
    config = FakeConfig(epochs=1000, rows=20, cap_minutes=2.0 / 60, step_s=1 / 16, lr_schedule="cosine")
    trainer = FakeTrainer(config, tmp_path / "run")
    summary = trainer.fit(progress=False)
    assert summary["stopped_by"] == "wall-clock cap" and summary["epochs"] == 3  # 2 s: 32 steps of 10 an epoch
    assert len(trainer.history) == summary["epochs"] and not any(r["partial_epoch"] for r in trainer.history)
    assert summary["steps"] == summary["epochs"] * 10  # the unfinished epoch's steps were dropped
    assert torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)["step"] == summary["steps"]
    assert len(trainer.lrs_seen) > summary["steps"]
    steps = 1000 * 10  # the schedule still spans every epoch's steps, not the cap's minutes
    assert trainer.lrs_seen == pytest.approx([scheduled_lr(0.1, "cosine", i / steps)
                                              for i in range(len(trainer.lrs_seen))])
    budgeted = FakeTrainer(FakeConfig(epochs=1000, max_minutes=1.0, cap_minutes=2.0 / 60, step_s=1 / 16),
                           tmp_path / "both").fit(progress=False)
    assert budgeted["stopped_by"] == "wall-clock cap"  # the cap comes first


def test_a_run_stopped_by_its_cap_resumes_to_the_straight_runs_weights(tmp_path):
    """The cap counts each run's own training time, so reruns of a slow machine finish the recipe's model."""
    straight = FakeTrainer(FakeConfig(epochs=8, rows=20), tmp_path / "straight")
    straight.fit(progress=False)
    stops = []
    for _ in range(12):
        trainer = FakeTrainer(FakeConfig(epochs=8, rows=20, cap_minutes=2.0 / 60, step_s=1 / 16),
                              tmp_path / "capped")
        trainer.resume()
        stops.append(trainer.fit(progress=False)["stopped_by"])
        if stops[-1] == "epochs":
            break
    assert stops == ["wall-clock cap", "wall-clock cap", "epochs"]  # 3 epochs a run, 8 in all
    assert without_times(trainer.history) == without_times(straight.history)
    assert trainer.weight.item() == straight.weight.item() and trainer.best_holdout == straight.best_holdout


def test_a_cap_inside_the_first_epoch_is_an_error(tmp_path):
    trainer = FakeTrainer(FakeConfig(epochs=5, rows=40, cap_minutes=0.5 / 60, step_s=1 / 16), tmp_path / "run")
    with pytest.raises(ValueError, match=r"inside its first epoch; give it a cap above one epoch's time"):
        trainer.fit(progress=False)


def test_resume_continues_to_the_same_history_and_weights(tmp_path):
    straight = FakeTrainer(FakeConfig(epochs=4), tmp_path / "straight")
    straight.fit(progress=False)
    FakeTrainer(FakeConfig(epochs=2), tmp_path / "split").fit(progress=False)
    resumed = FakeTrainer(FakeConfig(epochs=4), tmp_path / "split")  # epochs may change on resume
    assert resumed.resume() and resumed.epoch == 2 and resumed.step == 8
    resumed.fit(progress=False)
    assert without_times(resumed.history) == without_times(straight.history)
    assert resumed.weight.item() == straight.weight.item() and resumed.best_holdout == straight.best_holdout
    assert not FakeTrainer(FakeConfig(), tmp_path / "empty").resume()
    with pytest.raises(ValueError, match=r"other settings \(\['lr'\]\)"):
        FakeTrainer(FakeConfig(epochs=4, lr=0.2), tmp_path / "split").resume()


def test_progress_false_shows_no_bars_in_any_epoch(tmp_path, capsys):
    FakeTrainer(FakeConfig(epochs=3), tmp_path / "quiet").fit(progress=False)
    assert capsys.readouterr().err == ""
    FakeTrainer(FakeConfig(epochs=3), tmp_path / "bars").fit(progress=True)
    err = capsys.readouterr().err
    assert all(f"epoch {k}/3" in err for k in (1, 2, 3))


def test_learning_rate_follows_the_schedule_over_the_steps_with_short_batches_skipped(tmp_path):
    """9 rows in batches of 2: the last batch of one row is skipped, but counts in the steps per epoch (5)."""
    trainer = FakeTrainer(FakeConfig(epochs=3, rows=9, lr_schedule="cosine"), tmp_path / "run")
    trainer.fit(progress=False)
    assert trainer.step == 12 and set(trainer.batch_sizes_seen) == {2}
    expected = [scheduled_lr(0.1, "cosine", step / (3 * 5)) for step in range(12)]
    np.testing.assert_allclose(trainer.lrs_seen, expected, rtol=1e-12)


def test_tensorboard_gets_the_training_and_holdout_scalars(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    FakeTrainer(FakeConfig(epochs=3, rows=14), tmp_path / "run").fit(progress=False)  # 21 steps: one log at 20
    events = EventAccumulator(str(tmp_path / "run" / "tb"))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    assert {"train/loss", "train/weight", "train/lr", "holdout/loss", "holdout/loss_vs_minutes"} <= tags
    assert [event.step for event in events.Scalars("train/loss")] == [20]
    assert [event.step for event in events.Scalars("holdout/loss")] == [7, 14, 21]


def test_a_failed_checkpoint_write_leaves_the_previous_one_whole(tmp_path, monkeypatch):
    run_dir = tmp_path / "run"
    trainer = FakeTrainer(FakeConfig(epochs=1), run_dir)
    trainer.fit(progress=False)
    before = {name: (run_dir / name).read_bytes() for name in ("checkpoint.pt", "history.json")}

    def save_half_then_fail(obj, path):
        with open(path, "wb") as handle:
            handle.write(b"half a checkpoint")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", save_half_then_fail)
    with pytest.raises(OSError, match="disk full"):
        trainer.save_checkpoint()
    assert {name: (run_dir / name).read_bytes() for name in before} == before
    assert sorted(path.name for path in run_dir.iterdir()) == ["best.pt", "checkpoint.pt", "config.json",
                                                               "history.json", "tb"]


# --------------------------------------------------------------------------------------------------- the flags
GPU_FLAGS = ("--lr-scaling", "--warmup-epochs", "--data-on-device", "--compile", "--no-tf32")
COMMAND_FLAGS = {
    posenet: {"--source", "--contact", "--paired", "--out", "--data", "--image-size", "--epochs", "--batch-size",
              "--lr", "--beta", "--holdout", "--patience-epochs", "--shift", "--seed", "--threads", "--blur",
              "--erase", "--max-minutes", "--cap-minutes", "--lr-schedule", "--translators", "--variables", "--resume",
              "--device", "--no-amp", "--wandb", *GPU_FLAGS},
    translator: {"--arch", "--paired", "--out", "--data", "--lr-schedule", "--shear-decoder", "--flow",
                 "--image-size", "--base-channels", "--max-channels", "--decoder-scale", "--epochs", "--batch-size",
                 "--lr", "--l1-weight", "--density-weight", "--gan-weight", "--holdout", "--patience-epochs", "--seed",
                 "--threads", "--max-minutes", "--cap-minutes", "--pose-net", "--pose-weight", "--pose-variables",
                 "--teacher", "--init-weights", "--no-template", "--resume", "--export", "--device", "--no-amp",
                 "--wandb",
                 *GPU_FLAGS},
    rl: {"--algo", "--out", "--timesteps", "--obs-mode", "--image-size", "--n-envs", "--n-steps", "--batch-size",
         "--learning-rate", "--checkpoint-steps", "--seed", "--threads", "--resume", "--quiet", "--device", "--task",
         "--minutes", "--observation", "--history", "--no-randomise", "--vec", "--n-epochs", "--gamma", "--net-arch",
         "--no-normalize", "--residual-bound", "--asymmetric-critic", "--bc-steps", "--bc-rounds", "--bc-epochs",
         "--bc-noise", "--eval-steps", "--eval-max-steps", "--preset", "--wandb"},
}
REQUIRED = {posenet: ["--source", "real", "--contact", "surface", "--paired", "p"],
            translator: ["--paired", "p"], rl: []}
CONFIGS = {posenet: posenet_config.PosenetTrainConfig, translator: translator_config.TranslatorTrainConfig,
           rl: rl.RLTrainConfig}


def parser_of(module) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    return parser


@pytest.mark.parametrize("module", [posenet, translator, rl], ids=lambda module: module.__name__)
def test_command_flags_keep_their_names_and_defaults_and_all_have_help(module):
    parser = parser_of(module)
    options = {option for action in parser._actions for option in action.option_strings} - {"-h", "--help"}
    assert options == COMMAND_FLAGS[module]
    assert all(action.help for action in parser._actions)
    args = parser.parse_args(["--out", "o", *REQUIRED[module]])
    # train rl's flags read None when left out, so that --preset can fill them (rl.config_of)
    config = rl.config_of(args) if module is rl else flags.config_from_args(CONFIGS[module], args)
    given = {posenet: {"source": "real", "contact": "surface", "paired_dirs": ("p",)},
             translator: {"paired_dirs": ("p",)}, rl: {}}[module]
    assert config == CONFIGS[module](**given)  # every other field at its dataclass default


def test_flags_set_every_kind_of_field():
    args = parser_of(translator).parse_args(
        ["--out", "o", "--paired", "a", "b", "--no-template", "--shear-decoder", "--image-size", "64", "--lr", "2e-3",
         "--max-minutes", "1.5", "--pose-net", "g.pt", "--pose-weight", "20", "--pose-variables", "rx_deg", "ry_deg",
         "--flow", "8"])
    config = flags.config_from_args(translator_config.TranslatorTrainConfig, args)
    assert (config.paired_dirs, config.template, config.shear_decoder, config.image_size_px, config.lr) == (
        ("a", "b"), False, True, 64, 2e-3)
    assert (config.max_minutes, config.pose_weight, config.pose_variables, config.flow_px) == (
        1.5, 20.0, ("rx_deg", "ry_deg"), 8)
    args = parser_of(posenet).parse_args(["--out", "o", "--source", "shpix2pix", "--contact", "edge", "--paired", "p",
                                          "--blur", "1.0", "--translators", "w1.pt", "w2.pt"])
    config = flags.config_from_args(posenet_config.PosenetTrainConfig, args)
    assert (config.blur_px, config.translators, config.max_minutes) == (1.0, ("w1.pt", "w2.pt"), None)
    with pytest.raises(SystemExit):
        parser_of(rl).parse_args(["--out", "o", "--obs-mode", "oracle"])
    with pytest.raises(ValueError, match=r"flags for \['nonsense'\]"):
        flags.config_flags(argparse.ArgumentParser(), rl.RLTrainConfig, {"nonsense": "x"})


def test_help_of_the_training_commands_imports_neither_torch_nor_pybullet():
    code = ("import contextlib, io, sys\n"
            "from simshear_gym.cli import main\n"
            "for command in ('posenet', 'translator', 'rl'):\n"
            "    with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.suppress(SystemExit):\n"
            "        main(['train', command, '--help'])\n"
            "    assert '--out' in out.getvalue(), out.getvalue()\n"
            "print(sorted(m for m in ('torch', 'pybullet') if m in sys.modules))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def _paired_set_on_disk(root, n=20, size=16):
    """A replayed paired set (sim renders, shear, real images) of n surface contacts, written as simshear writes it."""
    import pandas as pd

    from simshear_gym.data.labels import MOVE_COLUMNS, POSE_COLUMNS, SHEAR_COLUMNS
    from simshear_gym.data.tactile_set import image_name, write_image, write_targets

    rng = np.random.default_rng(0)
    poses, moves = np.zeros((n, 6)), rng.uniform(-3, 3, (n, 6))
    poses[:, 2], poses[:, 3], poses[:, 4] = rng.uniform(2, 5, n), rng.uniform(-10, 10, n), rng.uniform(-10, 10, n)
    names = [image_name(i) for i in range(n)]
    columns = {**dict(zip(POSE_COLUMNS, poses.T)), **dict(zip(MOVE_COLUMNS, moves.T))}
    for kind, extra, meta in [("real", {}, {}),
                              ("paired", {"real_image": names, **dict(zip(SHEAR_COLUMNS, moves.T))},
                               {"contact": "surface", "real_set": str(root / "real"),
                                "real_set_relative_to_data_root": False})]:
        (root / kind / "images").mkdir(parents=True)
        for name in names:
            write_image(root / kind / "images", name, rng.integers(0, 255, (size, size), dtype=np.uint8))
        write_targets(root / kind, pd.DataFrame({"sensor_image": names, **columns, **extra}), meta)
    return root / "paired"


def test_train_commands_run_resume_and_refuse_a_second_run_over_a_checkpoint(tmp_path):
    from simshear_gym.cli import main

    paired = str(_paired_set_on_disk(tmp_path / "sets"))
    commands = {
        "posenet": ["train", "posenet", "--source", "sim", "--contact", "surface", "--paired", paired,
                    "--image-size", "16", "--batch-size", "8", "--holdout", "0.2", "--threads", "1"],
        "translator": ["train", "translator", "--arch", "pix2pix", "--paired", paired, "--image-size", "16",
                       "--base-channels", "2", "--max-channels", "4", "--batch-size", "8", "--holdout", "0.2",
                       "--threads", "1", "--no-template"],
    }
    for name, command in commands.items():
        out = tmp_path / name
        assert main([*command, "--out", str(out), "--epochs", "1"]) == 0
        config = json.loads((out / "config.json").read_text())
        assert config["paired_dirs"] == [paired] and config["image_size_px"] == 16 and config["threads"] == 1
        assert main([*command, "--out", str(out), "--epochs", "2"]) == 2  # a checkpoint there, and no --resume
        assert main([*command, "--out", str(out), "--epochs", "2", "--resume"]) == 0
        assert [r["epoch"] for r in json.loads((out / "history.json").read_text())["epochs"]] == [1, 2]
    assert json.loads((tmp_path / "translator" / "config.json").read_text())["template"] is False


def test_torch_free_copies_of_model_constants_agree_with_the_models():
    from simshear_gym.models.gdnn import GDNNConfig
    from simshear_gym.models.translator import ARCHS

    assert translator_config.ARCHS == ARCHS
    config, gdnn = posenet_config.PosenetTrainConfig(paired_dirs=("x",)), GDNNConfig()
    for name in ("image_size_px", "conv_channels", "conv_kernels", "dense", "dropout"):
        assert getattr(config, name) == getattr(gdnn, name), name
