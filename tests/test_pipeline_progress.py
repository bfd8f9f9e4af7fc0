"""Long pipeline work says where it is: one line per epoch with an ETA inside a training stage (its tensorboard
folder named at its start), and a ``smoke`` run labelled as a plumbing check in its output and manifest."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from simshear_gym.pipelines.stages import epoch_line, report_epochs, training_start_line


def test_the_epoch_line_gives_the_epoch_the_holdout_and_the_time_left_at_the_mean_pace():
    line = epoch_line("translator/surface_shpix2pix", {"epoch": 3, "elapsed_s": 180.0, "holdout_mape": 0.1234},
                      epochs=12, metric="mape")
    assert line == "[translator/surface_shpix2pix] epoch 3/12: 3.0 min, holdout mape 0.1234; ETA 9.0 min"
    last = epoch_line("posenet/edge_real", {"epoch": 5, "elapsed_s": 60.0, "holdout_nll": -2.5}, epochs=5,
                      metric="nll")
    assert last.endswith("epoch 5/5: 1.0 min, holdout nll -2.5; ETA 0 s")
    short = epoch_line("posenet/edge_real", {"epoch": 1, "elapsed_s": 4.2, "holdout_nll": 3.0}, epochs=3, metric="nll")
    assert short.endswith("epoch 1/3: 4 s, holdout nll 3; ETA 8 s")


def test_a_training_stage_names_its_epochs_and_tensorboard_folder_as_it_starts(tmp_path):
    assert training_start_line("posenet/edge_real", 20, tmp_path / "tb") == (
        f"[posenet/edge_real] training 20 epochs; tensorboard --logdir {tmp_path / 'tb'}")


class FakeTrainer:
    """The part of :class:`simshear_gym.train.loop.EpochTrainer` that report_epochs reads: after each epoch the
    loop appends a history record and calls ``log_epoch(writer)``."""

    metric = "nll"

    def __init__(self) -> None:
        self.config = SimpleNamespace(epochs=4)
        self.history: list[dict] = []
        self.tensorboard_calls = 0

    def log_epoch(self, writer) -> None:
        self.tensorboard_calls += 1

    def fit(self) -> None:
        for epoch in range(1, self.config.epochs + 1):
            self.history.append({"epoch": epoch, "elapsed_s": 30.0 * epoch, "holdout_nll": 1.0 / epoch})
            self.log_epoch(writer=None)


def test_report_epochs_logs_a_line_per_epoch_and_keeps_the_trainers_own_logging():
    trainer, lines = FakeTrainer(), []
    report_epochs(trainer, "posenet/surface_real", lines.append)
    trainer.fit()
    assert trainer.tensorboard_calls == 4
    assert [line.split(":")[0] for line in lines] == [f"[posenet/surface_real] epoch {e}/4" for e in (1, 2, 3, 4)]
    assert lines[0].endswith("ETA 1.5 min") and lines[-1].endswith("ETA 0 s")


@pytest.mark.slow
def test_a_smoke_run_prints_its_epochs_and_tensorboard_and_says_it_is_a_plumbing_check(tmp_path, capfd):
    from simshear_gym.pipelines.config import load_config
    from simshear_gym.pipelines.run import run_pipeline
    from tests.test_pipeline_check import write_lab

    data = tmp_path / "data"
    config = load_config(write_lab(data, rows=30))
    out = tmp_path / "run"
    manifest = run_pipeline(config, out, data, "smoke", ("adapt", "collect", "translator", "posenet"), workers=1,
                            jobs=1)
    printed = capfd.readouterr().out
    assert "plumbing check" in manifest["purpose"]
    assert json.loads((out / "manifest.json").read_text())["purpose"] == manifest["purpose"]
    assert printed.splitlines()[0].startswith("profile smoke: a plumbing check")
    trained = [r["stage"] for r in manifest["results"] if r["stage"].startswith(("translator/", "posenet/"))]
    assert trained
    for stage in trained:
        assert f"[{stage}] epoch 1/1: " in printed and "ETA" in printed
        assert f"[{stage}] training 1 epoch; tensorboard --logdir " in printed


def test_the_cpus_in_use_are_counted_from_the_kernels_counters_not_the_lagging_load_average(tmp_path, monkeypatch):
    """Two readings of /proc/stat's first line: the share of the window not idle, times the CPUs; None where the
    counters cannot be read (the estimate then falls back to the load average)."""
    import os

    from simshear_gym.pipelines import estimate

    stat = tmp_path / "stat"
    readings = iter(["cpu 100 0 100 700 100 0 0 0 0 0\n", "cpu 175 0 125 800 100 0 0 0 0 0\n"])

    def sleep(seconds):  # the window passes: the counters move on
        stat.write_text(next(readings))

    stat.write_text(next(readings))
    monkeypatch.setattr(estimate.time, "sleep", sleep)
    busy = estimate.busy_cpus_now(window_s=1.0, stat=str(stat))
    assert busy == pytest.approx(0.5 * (os.cpu_count() or 1))  # 100 of 200 ticks not idle
    assert estimate.busy_cpus_now(window_s=0.0, stat=str(tmp_path / "missing")) is None


def test_the_estimate_measures_the_load_and_says_how_it_skews_the_figure():
    from simshear_gym.pipelines.estimate import format_estimate, load_note, machine_load

    idle = machine_load(jobs=2, busy_cpus=0.05, cpus=2)
    assert {key: idle[key] for key in ("busy_cpus", "cpus", "jobs", "slowdown", "busy")} == {
        "busy_cpus": 0.05, "cpus": 2, "jobs": 2, "slowdown": 1.02, "busy": False}
    busy = machine_load(jobs=2, busy_cpus=3.5, cpus=2)  # the loaded 2-core machine
    assert busy["busy"] and busy["slowdown"] == 2.75 and busy["measured_by"] == "given"
    assert load_note(idle, 26.0).startswith("machine idle enough (0.05 of 2 CPUs in use")
    note = load_note(busy, 89.0)
    assert note.startswith("machine busy: 3.50 of 2 CPUs in use") and "about 2.8x" in note and "about 32.4 min" in note
    measured = machine_load(jobs=1)  # this machine, now: whatever its load, the record's fields are there
    assert measured["cpus"] >= 1 and 0 <= measured["busy_cpus"] and measured["load_1min"] >= 0
    assert measured["slowdown"] >= 1 and measured["measured_by"] in ("/proc/stat over 2 s", "1-minute load average")
    result = {"steps": [], "sensor": "lab", "profile": "quick", "training_wall_min": 89.0, "jobs": 2,
              "lane_busy_min": 150.0, "load": busy}
    assert format_estimate(result).splitlines()[-1] == note
