"""Bad input never passes silently and never ends in a traceback (issue 24, bullet 4; issue 41, items 2-4).

A sweep: every kind of malformed input, given to every command that reads it (``collect``, ``train translator``,
``train posenet``, ``evaluate posenet``, ``pipeline check``, ``pipeline run``, ``rollout``), must exit non-zero with
exactly one ``simshear: error:`` line naming the file, column, row or host and what was expected. The commands run
in-process through :func:`simshear_gym.cli.main` (an exception escaping it is the traceback a user would see); two
run as real processes too. Issue 41 adds: weights files that are truncated, random, empty, bit-flipped or of another
model (.pt, .onnx); PNG decompression bombs; a column twice in a CSV header; labels far outside the format's declared
range; a full disk on a write; a config name that would write outside its run folder; and the decoded-image cache,
which must not serve old pixels for an image overwritten in place.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import zlib
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
    from simshear_gym.models.zoo import posenet_weights

    return str(posenet_weights("surface"))


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
def _duplicate_column(directory: Path) -> None:
    """pose_3 named twice (pandas would read the first and call the second 'pose_3.1')."""
    lines = (directory / "targets.csv").read_text().splitlines()
    lines = [lines[0] + ",pose_3"] + [line + ",0" for line in lines[1:]]
    (directory / "targets.csv").write_text("\n".join(lines) + "\n")


def png_bomb(width: int = 8000, height: int = 8000) -> bytes:
    """A valid 8-bit grey PNG of ``width`` x ``height`` black pixels: 64 MB of pixels in about 60 KB."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    compressor = zlib.compressobj(9)
    row = b"\x00" * (width + 1)
    body = b"".join(compressor.compress(row) for _ in range(height)) + compressor.flush()
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", body) + chunk(b"IEND", b""))


CASES.update({
    "duplicate_column": (_duplicate_column, ("targets.csv: column 'pose_3' appears twice in the header",)),
    "huge_value": (lambda d: _set_cell(d, 3, "pose_3", "1e300"),
                   ("targets.csv: row 3, column 'pose_3': value 1e+300", "outside the declared range")),
    "png_bomb": (lambda d: (d / "images" / "image_5.png").write_bytes(png_bomb()),
                 ("image_5.png: its header claims 8000x8000 px", "decompression bomb")),
    "truncated_png": (lambda d: (d / "images" / "image_6.png").write_bytes(
        (d / "images" / "image_6.png").read_bytes()[:40]), ("image_6.png: cannot be read as an image",)),
})
PAIRED_ONLY: dict[str, tuple[Callable[[Path], None], tuple[str, ...]]] = {
    "missing_meta_json": (lambda d: (d / "meta.json").unlink(), ("meta.json: missing",)),
    "missing_real_image_column": (lambda d: pd.read_csv(d / "targets.csv").drop(columns=["real_image"]).to_csv(
        d / "targets.csv", index=False), ("targets.csv: column 'real_image' is missing",)),
}
IMAGE_CASES = {"missing_image", "wrong_image_size", "corrupt_png", "missing_images_dir", "png_bomb",
               "truncated_png"}  # collect reads no images


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
    if trainer == "train posenet real" and case in ("wrong_image_size", "corrupt_png", "png_bomb", "truncated_png"):
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


# -- weights files ---------------------------------------------------------------------------------------------


def _weights_cases(good: Path) -> dict[str, tuple[Callable[[Path], None], tuple[str, ...]]]:
    """name -> (write a bad weights file at the path, what the error line must say besides the file)."""
    from simshear_gym.models.zoo import shipped_translators

    def bit_flip(path: Path) -> None:
        shutil.copyfile(good, path)
        shutil.copyfile(str(good) + ".sha256", str(path) + ".sha256")
        data = bytearray(path.read_bytes())
        data[len(data) * 3 // 4] ^= 0x04  # in the tensors: torch itself would load it
        path.write_bytes(bytes(data))

    return {
        "zero_bytes": (lambda path: path.write_bytes(b""), ("empty (0 bytes)",)),
        "truncated": (lambda path: path.write_bytes(good.read_bytes()[:len(good.read_bytes()) // 2]),
                      ("not a readable weights file",)),
        "random_bytes": (lambda path: path.write_bytes(np.random.default_rng(0).bytes(4096)),
                         ("not a readable weights file",)),
        "wrong_architecture": (lambda path: shutil.copyfile(shipped_translators()[("shpix2pix", "surface")], path),
                               ("not a simshear posenet file",)),
        "bit_flipped": (bit_flip, ("sha256", "differs", "corrupt")),
    }


@pytest.mark.parametrize("case", ["zero_bytes", "truncated", "random_bytes", "wrong_architecture", "bit_flipped"])
def test_evaluate_posenet_with_bad_weights(tmp_path, capsys, case):
    write_sets(tmp_path / "data")
    bad = tmp_path / "bad.pt"
    malform, expected = _weights_cases(Path(posenet_path()))[case]
    malform(bad)
    argv = ["evaluate", "posenet", "--model", f"real={bad}", "--contact", "surface", "--data", str(tmp_path / "data"),
            "--out", str(tmp_path / "results"), "--threads", "1"]
    line = assert_one_error_line(*run_cli(argv, capsys), ("bad.pt", *expected))
    assert "Traceback" not in line
    assert not (tmp_path / "results" / "posenet.json").exists()


@pytest.mark.parametrize("case", ["zero_bytes", "truncated", "random_bytes", "bit_flipped"])
def test_translator_weights_that_are_bad_are_one_error_naming_the_file(tmp_path, case):
    from simshear_gym.models.translator_runtime import load_translator
    from simshear_gym.models.zoo import shipped_translators

    good = shipped_translators()[("shpix2pix", "surface")]
    bad = tmp_path / "shpix2pix_surface.pt"
    _weights_cases(good)[case][0](bad)
    with pytest.raises(ValueError, match=r"shpix2pix_surface\.pt: "):
        load_translator(bad, runtime="torch")


@pytest.mark.parametrize("case", ["zero_bytes", "random_bytes", "bit_flipped", "wrong_architecture"])
def test_onnx_translators_that_are_bad_are_one_error_naming_the_file(tmp_path, case):
    """A bit-flipped .onnx loads in ONNX Runtime and makes black images: its recorded sha256 refuses it."""
    pytest.importorskip("onnxruntime")
    from simshear_gym.models.translator_runtime import OnnxTranslator, onnx_path_for
    from simshear_gym.models.zoo import translator_weights

    good = onnx_path_for(translator_weights("surface"))
    bad = tmp_path / "bad.onnx"
    if case == "wrong_architecture":  # an ONNX graph of something else: a one-input identity
        import onnx
        from onnx import TensorProto, helper

        graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "other",
                                  [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4])],
                                  [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 4])])
        onnx.save_model(helper.make_model(graph), bad)
        expected = r"bad\.onnx: not a simshear ONNX translator"
    else:
        _weights_cases(good)[case][0](bad)
        expected = r"bad\.onnx: (sha256 .* differs|not an ONNX model)"
    with pytest.raises(ValueError, match=expected):
        OnnxTranslator(bad)


def test_every_shipped_weights_file_carries_its_checksum():
    """The shipped .pt and .onnx files each have a <file>.sha256 beside them, and it matches."""
    from simshear_gym.io import checksum_path, verify_checksum
    from simshear_gym.models.zoo import WEIGHTS_DIR

    files = sorted([*WEIGHTS_DIR.rglob("*.pt"), *WEIGHTS_DIR.rglob("*.onnx")])
    files = [path for path in files if "policies" not in path.parts]  # a policy's sha256 is in its model.json
    assert len(files) >= 10
    for path in files:
        assert checksum_path(path).is_file(), path
        assert verify_checksum(path), path


# -- images and the decoded-image cache ---------------------------------------------------------------------------


def test_an_image_overwritten_in_place_is_not_served_from_the_cache(tmp_path):
    """The cache is keyed on each image's size and modification time, not the folder's: an image replaced in place
    (the folder's own time put back, as a copy tool may leave it) is decoded afresh."""
    from simshear_gym.data.tactile_set import read_set

    real, _ = write_sets(tmp_path / "data")
    first = read_set(real).load_images()
    assert read_set(real).load_images() is not None  # cached now
    folder_times = os.stat(real / "images")
    replaced = 255 - first[2]
    write_image(real / "images", "image_3.png", replaced)
    os.utime(real / "images", ns=(folder_times.st_atime_ns, folder_times.st_mtime_ns))
    again = read_set(real).load_images()
    np.testing.assert_array_equal(again[2], replaced)
    np.testing.assert_array_equal(again[0], first[0])


# -- a full disk -------------------------------------------------------------------------------------------------


def test_a_full_disk_is_one_line_naming_the_file_and_the_free_space(tmp_path, capsys, monkeypatch):
    """ENOSPC on a write (simulated: every text write fails as a full disk does)."""
    write_sets(tmp_path / "data")

    def no_space(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(self))

    monkeypatch.setattr(Path, "write_text", no_space)
    argv = ["evaluate", "posenet", "--model", f"real={posenet_path()}", "--contact", "surface", "--data",
            str(tmp_path / "data"), "--out", str(tmp_path / "results"), "--threads", "1"]
    line = assert_one_error_line(*run_cli(argv, capsys), ("cannot be written: the disk is full", "free in"))
    assert str(tmp_path / "results") in line
    assert not [p for p in (tmp_path / "results").glob(".*tmp*")]  # no half-written temporary file left


def test_a_full_disk_under_torch_save_is_one_line(tmp_path, capsys, monkeypatch):
    """torch's writer says only "file write failed" (a RuntimeError); with the disk (nearly) full it is the full
    disk, named with the file and the free space, and the previous checkpoint is left whole."""
    import torch

    import simshear_gym.io as sio

    _, paired = write_sets(tmp_path / "data")

    def failing_save(obj, path, *args, **kwargs):
        Path(path).write_bytes(b"PK\x03\x04 partial")
        raise RuntimeError("[enforce fail at inline_container.cc:664] . PytorchStreamWriter failed writing file "
                           "data/0: file write failed")

    monkeypatch.setattr(torch, "save", failing_save)
    monkeypatch.setattr(sio.shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(10**9, 10**9 - 4096, 4096))
    argv = TRAINERS["train posenet sim"] + ["--paired", str(paired), "--out", str(tmp_path / "run")]
    line = assert_one_error_line(*run_cli(argv, capsys), ("cannot be written: the disk is full", "4.0 KiB free"))
    assert ".pt" in line


# -- names in a pipeline config -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["../escaped", "a/b", "..", "with space"])
def test_a_dataset_name_that_is_not_a_name_is_refused_before_anything_is_written(tmp_path, capsys, name):
    config = _lab(tmp_path / "lab")
    text = config.read_text()
    table = next(line for line in text.splitlines() if line.startswith("[datasets."))
    old = table[len("[datasets."):].split("]")[0].split(".")[0]
    config.write_text(text.replace(f"[datasets.{old}", f'[datasets."{name}"'))
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    argv = ["pipeline", "run", str(config), "--profile", "smoke", "--data", str(tmp_path / "lab"), "--out",
            str(tmp_path / "out" / "run")]
    line = assert_one_error_line(*run_cli(argv, capsys), ("lab.toml", repr(name), "is not a name"))
    assert "no path separators" in line
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before  # nothing written anywhere


def test_a_stage_cannot_write_outside_its_run_folder(tmp_path):
    from simshear_gym.pipelines.stages import StageFolderError, StageRunner

    runner = StageRunner(tmp_path / "run", log=lambda text: None)
    ran = []
    with pytest.raises(StageFolderError, match="outside the run folder"):
        runner.run("adapt/../../escaped", {"k": 1}, lambda folder: ran.append(folder) or {})
    assert ran == [] and not (tmp_path / "escaped").exists()
    with pytest.raises(StageFolderError, match="outside the run folder"):
        runner.run("adapt/ok", {"k": 1}, lambda folder: {"outputs": {"set": runner.relative(tmp_path / "x")}})
