"""The pipeline's step graph (:mod:`simshear_gym.pipelines.stages`): priority by the longest chain, every step
after the ones it needs, in this process or in worker processes; a failing step stops the run with its name, and so
does a training stopped by its wall-clock cap, unrecorded, so that the rerun continues it."""

from __future__ import annotations

import json
import os
from functools import partial
from pathlib import Path

import pytest

from simshear_gym.cli import is_input_error
from simshear_gym.pipelines.stages import (
    RECORD,
    StageResult,
    StageRunner,
    StageStopped,
    Step,
    file_fingerprint,
    order_steps,
    run_steps,
)
from simshear_gym.train.runs import CAP_STOP


def _write(value: str, runner: StageRunner, done: dict) -> StageResult:
    """A step that records the values of the steps it needs beside its own."""
    seen = sorted(result.outputs["value"] for result in done.values())

    def work(folder: Path) -> dict:
        (folder / "seen.json").write_text(json.dumps(seen))
        return {"outputs": {"value": value}, "metrics": {"seen": seen}}

    return runner.run(f"step/{value}", {"value": value, "seen": seen}, work)


def _fail(runner: StageRunner, done: dict) -> StageResult:
    raise ValueError("bad settings in step c")


def _capped_once(runner: StageRunner, done: dict) -> StageResult:
    """A training that its wall-clock cap stops on the first run (after 2 epochs) and that the rerun finishes."""

    def work(folder: Path) -> dict:
        runs = folder / "runs.txt"
        runs.write_text(runs.read_text() + "x" if runs.exists() else "x")
        first = runs.read_text() == "x"
        metrics = {"epochs": 2, "elapsed_s": 60.0, "stopped_by": CAP_STOP} if first else {
            "epochs": 5, "elapsed_s": 150.0, "stopped_by": "epochs"}
        return {"outputs": {"value": "c"}, "metrics": metrics}

    return runner.run("step/c", {"value": "c"}, work)


def graph(fail: bool = False, capped: bool = False) -> list[Step]:
    c = _fail if fail else _capped_once if capped else partial(_write, "c")
    return [Step("a", partial(_write, "a"), cost=1.0),
            Step("b", partial(_write, "b"), cost=3.0),
            Step("c", c, needs=("a",), cost=5.0),
            Step("d", partial(_write, "d"), needs=("b", "c"), cost=1.0)]


def test_the_longest_chain_starts_first():
    assert order_steps(graph()) == ["a", "c", "b", "d"]  # a -> c -> d costs 7, b -> d 4


def test_bad_graphs_are_refused():
    with pytest.raises(ValueError, match=r"step 'a' needs \['x'\]"):
        order_steps([Step("a", _fail, needs=("x",))])
    with pytest.raises(ValueError, match="cycle"):
        order_steps([Step("a", _fail, needs=("b",)), Step("b", _fail, needs=("a",))])


@pytest.mark.parametrize("jobs", [1, 2])
def test_every_step_sees_the_steps_it_needs(tmp_path, jobs):
    done = run_steps(graph(), tmp_path, jobs=jobs, log=lambda text: None)
    assert {name: result.record["metrics"]["seen"] for name, result in done.items()} == {
        "a": [], "b": [], "c": ["a"], "d": ["b", "c"]}
    again = run_steps(graph(), tmp_path, jobs=jobs, log=lambda text: None)
    assert not any(result.ran for result in again.values())  # each step cached under its key


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_failing_step_stops_the_run_and_says_which(tmp_path, jobs):
    with pytest.raises(ValueError, match="bad settings in step c"):  # bad input stays a one-line CLI error
        run_steps(graph(fail=True), tmp_path, jobs=jobs, log=lambda text: None)
    assert not (tmp_path / "step" / "d").exists()


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_training_stopped_by_its_cap_is_not_recorded_and_the_rerun_continues_it(tmp_path, jobs):
    with pytest.raises(StageStopped, match=r"\[step/c\] stopped by its wall-clock safety cap .* after 2 finished "
                                           r"epochs .* Rerun the same command to continue it") as stopped:
        run_steps(graph(capped=True), tmp_path, jobs=jobs, log=lambda text: None)
    assert is_input_error(stopped.value)  # the CLI prints it as one line, not a traceback
    folder = next((tmp_path / "step" / "c").iterdir())
    assert not (folder / RECORD).exists() and not (tmp_path / "step" / "d").exists()
    done = run_steps(graph(capped=True), tmp_path, jobs=jobs, log=lambda text: None)
    assert done["c"].ran and done["c"].record["resumed"] and done["c"].record["metrics"]["epochs"] == 5
    assert (folder / "runs.txt").read_text() == "xx" and done["d"].record["metrics"]["seen"] == ["b", "c"]


def _crash(runner: StageRunner, done: dict) -> StageResult:
    raise KeyError("z_mm")


def test_a_workers_bug_is_named_by_its_step(tmp_path):
    steps = [Step("a", partial(_write, "a")), Step("c", _crash, needs=("a",))]
    with pytest.raises(RuntimeError, match=r"pipeline step 'c' failed: 'z_mm'"):
        run_steps(steps, tmp_path, jobs=2, log=lambda text: None)


def test_a_data_sets_fingerprint_follows_its_contents_not_its_file_times(tmp_path):
    labels = tmp_path / "targets.csv"
    labels.write_text("sensor_image,pose_3\nimage_1.png,-1.5\n")
    before = file_fingerprint([labels])
    os.utime(labels, ns=(1, 1))  # a copied or re-provisioned data set: new times, same labels
    assert file_fingerprint([labels]) == before
    labels.write_text("sensor_image,pose_3\nimage_1.png,-2.5\n")
    assert file_fingerprint([labels]) != before
