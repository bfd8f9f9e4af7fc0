"""Bad input never passes silently and never ends in a traceback (issue 24, bullet 4).

A sweep: every kind of malformed input, given to every command that reads it (``collect``, ``train translator``,
``train posenet``, ``evaluate posenet``, ``pipeline check``, ``rollout``), must exit non-zero with exactly one
``simshear: error:`` line naming the file, column, row or host and what was expected. The commands run in-process
through :func:`simshear_gym.cli.main` (an exception escaping it is the traceback a user would see); two run as
real processes too.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from simshear_gym import cli
from simshear_gym.data.labels import MOVE_COLUMNS, POSE_COLUMNS, SHEAR_COLUMNS
from simshear_gym.data.paths import real_set_dir
from simshear_gym.data.tactile_set import image_name, write_image, write_targets

SIZE = 16
ROWS = 12
ROOT = Path(__file__).resolve().parents[1]


def posenet_path() -> str:
    from simshear_gym.models.posenet_io import shipped_posenet_path

    return str(shipped_posenet_path("surface"))


# -- sets on disk --------------------------------------------------------------------------------------------------


def write_sets(root: Path) -> tuple[Path, Path]:
    """A real surface shear val set (as tactip331 lays it out under ``root``) and a replayed paired set of it."""
    rng = np.random.default_rng(0)
    poses, moves = np.zeros((ROWS, 6)), rng.uniform(-3, 3, (ROWS, 6))
    poses[:, 2], poses[:, 3], poses[:, 4] = rng.uniform(2, 5, ROWS), rng.uniform(-10, 10, ROWS), rng.uniform(-10, 10,
                                                                                                           ROWS)
    names = [image_name(i) for i in range(ROWS)]
    labels = {**dict(zip(POSE_COLUMNS, poses.T)), **dict(zip(MOVE_COLUMNS, moves.T))}
    real = real_set_dir(root, "surface", "shear", "val")
    paired = root / "paired"
    for directory, extra, meta in [
        (real, {"obj_pose": ["[0, 0, 0, 0, 0, -48]"] * ROWS}, {"note": "real"}),
        (paired, {"real_image": names, **dict(zip(SHEAR_COLUMNS, moves.T))},
         {"contact": "surface", "real_set": str(real), "real_set_relative_to_data_root": False}),
    ]:
        (directory / "images").mkdir(parents=True)
        for name in names:
            write_image(directory / "images", name, rng.integers(0, 255, (SIZE, SIZE), dtype=np.uint8))
        write_targets(directory, pd.DataFrame({"sensor_image": names, **labels, **extra}), meta)
    return real, paired


def _edit_csv(directory: Path, edit: Callable[[list[str]], list[str]]) -> None:
    path = directory / "targets.csv"
    path.write_text("\n".join(edit(path.read_text().splitlines())) + "\n")


def _set_cell(directory: Path, row: int, column: str, value: str) -> None:
    table = pd.read_csv(directory / "targets.csv", dtype=str, keep_default_na=False)
    table.loc[row - 1, column] = value
    table.to_csv(directory / "targets.csv", index=False)


def _short_row(lines: list[str]) -> list[str]:
    fields = next(csv.reader([lines[2]]))[:-3]  # data row 2 lost its last three fields
    out = io.StringIO()
    csv.writer(out, lineterminator="").writerow(fields)
    lines[2] = out.getvalue()
    return lines


# name -> (malformation of a set directory, what the error line must name; {set} is the set's directory name)
CASES: dict[str, tuple[Callable[[Path], None], tuple[str, ...]]] = {
    "missing_image": (lambda d: (d / "images" / "image_2.png").unlink(),
                      ("image_2.png: missing", "row 2 of targets.csv")),
    "bad_csv_row": (lambda d: _edit_csv(d, lambda lines: lines[:4] + [lines[4] + ",1,2,3"] + lines[5:]),
                    ("targets.csv: not a readable CSV", "line 5")),
    "non_numeric_value": (lambda d: _set_cell(d, 3, "pose_3", "deep"),
                          ("targets.csv: row 3, column 'pose_3': value 'deep' is not a finite number",)),
    "nan_value": (lambda d: _set_cell(d, 2, "move_2", "nan"), ("row 2, column 'move_2'", "not a finite number")),
    "inf_value": (lambda d: _set_cell(d, 4, "move_1", "inf"), ("row 4, column 'move_1'", "not a finite number")),
    "short_row": (lambda d: _edit_csv(d, _short_row), ("targets.csv: row 2, column", "not a finite number")),
    "missing_column": (lambda d: pd.read_csv(d / "targets.csv").drop(columns=["pose_3"]).to_csv(
        d / "targets.csv", index=False), ("targets.csv: column 'pose_3' is missing",)),
    "header_only_csv": (lambda d: _edit_csv(d, lambda lines: lines[:1]), ("targets.csv: no data rows",)),
    "wrong_image_size": (lambda d: write_image(d / "images", "image_3.png", np.zeros((8, 8), np.uint8)),
                         ("image_3.png: image size 8x8 px, expected 16x16 px",)),
    "corrupt_png": (lambda d: (d / "images" / "image_4.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really"),
                    ("image_4.png: cannot be read as an image",)),
    "invalid_meta_json": (lambda d: (d / "meta.json").write_text("{'contact': surface"),
                          ("meta.json: not valid JSON",)),
    "meta_json_not_an_object": (lambda d: (d / "meta.json").write_text("[1, 2]"),
                                ("meta.json: expected a JSON object",)),
    "missing_images_dir": (lambda d: shutil.rmtree(d / "images"), ("images: missing",)),
}
PAIRED_ONLY: dict[str, tuple[Callable[[Path], None], tuple[str, ...]]] = {
    "missing_meta_json": (lambda d: (d / "meta.json").unlink(), ("meta.json: missing",)),
    "missing_real_image_column": (lambda d: pd.read_csv(d / "targets.csv").drop(columns=["real_image"]).to_csv(
        d / "targets.csv", index=False), ("targets.csv: column 'real_image' is missing",)),
}
IMAGE_CASES = {"missing_image", "wrong_image_size", "corrupt_png", "missing_images_dir"}  # collect reads no images


def run_cli(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = cli.main(argv)
    except SystemExit as exit_:  # argparse: its own one-line error, no traceback
        code = int(exit_.code or 0)
    except BaseException as error:  # noqa: BLE001 - what a user would see as a traceback
        pytest.fail(f"simshear {' '.join(argv[:2])} ended in a traceback: {type(error).__name__}: {error}")
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_error_line(code: int, out: str, err: str, expected: tuple[str, ...]) -> str:
    lines = [line for line in err.splitlines() if line.startswith("simshear: error:")]
    assert code != 0, f"exit 0 on bad input; output: {out}"
    assert "Traceback" not in err
    assert len(lines) == 1, err
    for text in expected:
        assert text in lines[0], (text, lines[0])
    return lines[0]


TRAINERS = {
    "train translator": ["train", "translator", "--arch", "pix2pix", "--image-size", str(SIZE), "--base-channels",
                         "2", "--max-channels", "4", "--batch-size", "4", "--holdout", "0.25", "--threads", "1",
                         "--no-template", "--epochs", "1"],
    "train posenet real": ["train", "posenet", "--source", "real", "--contact", "surface", "--image-size",
                           str(SIZE), "--batch-size", "4", "--holdout", "0.25", "--threads", "1", "--epochs", "1"],
    "train posenet sim": ["train", "posenet", "--source", "sim", "--contact", "surface", "--image-size",
                          str(SIZE), "--batch-size", "4", "--holdout", "0.25", "--threads", "1", "--epochs", "1"],
}


@pytest.mark.parametrize("trainer", list(TRAINERS))
@pytest.mark.parametrize("case", list(CASES) + list(PAIRED_ONLY))
def test_trainers_on_a_malformed_paired_set(tmp_path, capsys, trainer, case):
    if trainer == "train posenet real" and case in ("wrong_image_size", "corrupt_png"):
        pytest.skip("--source real reads the paired set's labels, not its sim images")
    _, paired = write_sets(tmp_path / "data")
    malform, expected = {**CASES, **PAIRED_ONLY}[case]
    malform(paired)
    argv = TRAINERS[trainer] + ["--paired", str(paired), "--out", str(tmp_path / "run")]
    line = assert_one_error_line(*run_cli(argv, capsys), expected)
    assert "paired" in line  # names the set


@pytest.mark.parametrize("trainer", ["train translator", "train posenet real"])
@pytest.mark.parametrize("case", ["inf_value", "missing_image", "corrupt_png", "header_only_csv"])
def test_trainers_on_a_malformed_real_set(tmp_path, capsys, trainer, case):
    real, paired = write_sets(tmp_path / "data")
    malform, expected = CASES[case]
    malform(real)
    argv = TRAINERS[trainer] + ["--paired", str(paired), "--out", str(tmp_path / "run")]
    line = assert_one_error_line(*run_cli(argv, capsys), expected)
    assert "csv_val" in line  # names the real set, not the paired one


def test_train_posenet_from_sim_images_needs_no_real_set(tmp_path, capsys):
    real, paired = write_sets(tmp_path / "data")
    shutil.rmtree(real)
    argv = TRAINERS["train posenet sim"] + ["--paired", str(paired), "--out", str(tmp_path / "run")]
    code, out, err = run_cli(argv, capsys)
    assert code == 0, err
    argv = TRAINERS["train posenet real"] + ["--paired", str(paired), "--out", str(tmp_path / "run_real")]
    assert_one_error_line(*run_cli(argv, capsys), ("csv_val/targets.csv: missing",))


@pytest.mark.parametrize("case", [c for c in CASES if c not in IMAGE_CASES])
def test_collect_on_a_malformed_real_set(tmp_path, capsys, case):
    real, _ = write_sets(tmp_path / "data")
    malform, expected = CASES[case]
    malform(real)
    argv = ["collect", "--replay", str(real), "--contact", "surface", "--image-size", "64", "--workers", "1",
            "--out", str(tmp_path / "out")]
    line = assert_one_error_line(*run_cli(argv, capsys), expected)
    assert "csv_val" in line
    assert not (tmp_path / "out" / "targets.csv").exists()


@pytest.mark.parametrize("case", list(CASES))
def test_evaluate_posenet_on_a_malformed_real_val_set(tmp_path, capsys, case):
    real, _ = write_sets(tmp_path / "data")
    malform, expected = CASES[case]
    malform(real)
    argv = ["evaluate", "posenet", "--model", f"real={posenet_path()}", "--contact", "surface", "--data",
            str(tmp_path / "data"), "--out", str(tmp_path / "results"), "--threads", "1"]
    assert_one_error_line(*run_cli(argv, capsys), expected)
    assert not (tmp_path / "results" / "posenet.json").exists()  # no metrics written, NaN or otherwise


# -- pipeline check on a lab's raw data ---------------------------------------------------------------------------


def _lab(root: Path) -> Path:
    sys.path.insert(0, str(ROOT / "tests"))
    try:
        from test_pipeline_check import GOOD, write_lab
    finally:
        sys.path.pop(0)
    write_lab(root)
    config = root / "lab.toml"
    config.write_text(GOOD)
    return config


LAB_CASES: dict[str, tuple[Callable[[Path], None], tuple[str, ...]]] = {
    "missing_image": (lambda d: (d / "frames" / "f3.png").unlink(), ("f3.png",)),
    "non_numeric_value": (lambda d: _lab_cell(d, 2, "depth_m", "deep"), ("depth_m",)),
    "nan_value": (lambda d: _lab_cell(d, 2, "depth_m", "nan"), ("depth_m",)),
    "inf_value": (lambda d: _lab_cell(d, 2, "roll_rad", "inf"), ("roll_rad",)),
    "missing_column": (lambda d: pd.read_csv(d / "labels.csv").drop(columns=["roll_rad"]).to_csv(
        d / "labels.csv", index=False), ("roll_rad",)),
    "header_only_csv": (lambda d: (d / "labels.csv").write_text((d / "labels.csv").read_text().splitlines()[0]
                                                                + "\n"), ("labels.csv",)),
    "corrupt_png": (lambda d: (d / "frames" / "f4.png").write_bytes(b"not a png"), ("f4.png",)),
}


def _lab_cell(root: Path, row: int, column: str, value: str) -> None:
    table = pd.read_csv(root / "labels.csv", dtype=str)
    table.loc[row - 1, column] = value
    table.to_csv(root / "labels.csv", index=False)


@pytest.mark.parametrize("case", list(LAB_CASES))
def test_pipeline_check_on_malformed_lab_data(tmp_path, capsys, case):
    config = _lab(tmp_path / "lab")
    malform, expected = LAB_CASES[case]
    malform(tmp_path / "lab")
    argv = ["pipeline", "check", str(config), "--data", str(tmp_path / "lab")]
    assert_one_error_line(*run_cli(argv, capsys), expected)


# -- the robot and the camera --------------------------------------------------------------------------------------


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]  # free once closed: nothing listens there


def _frames(folder: Path) -> Path:
    folder.mkdir(parents=True)
    for index in range(3):
        cv2.imwrite(str(folder / f"image_{index + 1}.png"), np.full((480, 640), 40 * index, np.uint8))
    return folder


def rollout_argv(tmp_path: Path, camera: str, port: int) -> list[str]:
    return ["rollout", "--robot", "127.0.0.1", "--camera", camera, "--controller", "servo", "--posenet",
            posenet_path(), "--steps", "2", "--image-size", "64", "--dashboard-port", str(port), "--motion-port",
            str(port), "--feedback-port", str(port), "--out", str(tmp_path / "run")]


def test_rollout_with_an_unreachable_robot(tmp_path, capsys):
    port = _closed_port()
    argv = rollout_argv(tmp_path, str(_frames(tmp_path / "frames")), port)
    assert_one_error_line(*run_cli(argv, capsys), (f"cannot connect to the MG400 dashboard port at 127.0.0.1:{port}",))


def test_rollout_with_a_missing_camera(tmp_path, capsys):
    argv = rollout_argv(tmp_path, str(tmp_path / "no-such-camera"), _closed_port())
    assert_one_error_line(*run_cli(argv, capsys), ("camera source", "no-such-camera",
                                                   "neither a device index, an existing video file nor an image"))


def test_rollout_with_looser_limits_needs_the_unsafe_flag(tmp_path, capsys):
    argv = rollout_argv(tmp_path, str(_frames(tmp_path / "frames")), _closed_port()) + ["--max-step-mm", "20"]
    assert_one_error_line(*run_cli(argv, capsys), ("--max-step-mm", "max_step_mm = 20.0", "--unsafe-limits"))


# -- as a user runs them: real processes -----------------------------------------------------------------------


@pytest.mark.parametrize("case", ["header_only_csv", "unreachable_robot"])
def test_the_simshear_process_prints_one_line_and_no_traceback(tmp_path, case):
    if case == "unreachable_robot":
        argv = rollout_argv(tmp_path, str(_frames(tmp_path / "frames")), _closed_port())
        expected = "cannot connect to the MG400"
    else:
        _, paired = write_sets(tmp_path / "data")
        CASES[case][0](paired)
        argv = TRAINERS["train posenet sim"] + ["--paired", str(paired), "--out", str(tmp_path / "run")]
        expected = "targets.csv: no data rows"
    result = subprocess.run([sys.executable, "-m", "simshear_gym.cli", *argv], capture_output=True, text=True,
                            cwd=ROOT, timeout=300)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("simshear: error:")]
    assert len(lines) == 1 and expected in lines[0], result.stderr


def test_no_bad_input_run_exits_0_with_nan_or_inf_in_its_output(tmp_path, capsys):
    """The one that did: inf in a move column passed collect, and evaluate posenet wrote NaN metrics, exit 0."""
    real, _ = write_sets(tmp_path / "data")
    _set_cell(real, 4, "move_1", "inf")
    argv = ["evaluate", "posenet", "--model", f"real={posenet_path()}", "--contact", "surface", "--data",
            str(tmp_path / "data"), "--out", str(tmp_path / "results"), "--threads", "1"]
    code, out, err = run_cli(argv, capsys)
    assert code != 0 and "column 'move_1'" in err
    written = [json.loads(p.read_text()) for p in (tmp_path / "results").glob("*.json")]
    assert written == [] and "nan" not in out.lower() and "inf" not in out.lower()
