"""``simshear evaluate collect-real``: ``simshear collect-real`` rehearsed on an emulated MG400 and a camera that
renders the configured stimulus, killed with SIGKILL at a random row and run again, per stimulus.

For each stimulus (``surface``: depth 3-5 mm, shear x, y +-3 mm and Rz +-5 deg, the sensor turned +-20 deg;
``edge``: offset +-6 mm, depth 3-5 mm, angle +-170 deg, the same shear: a flange turn ending next to the
MG400's R = +-180 deg is refused by the queued-move planning), half taps: an emulator runs in this
process (so its own record of every motion command outlives the killed collector), the collector runs as a child
process (``--robot`` the emulator, ``--camera rehearsal``: the stimulus rendered from the arm's feedback), is killed
when its ``targets.csv`` reaches a row drawn from ``--seed``, and is run again to the end. Then: rows (exactly the
protocol's), duplicate or missing images, images that do not decode, labels outside the protocol's ranges, the
emulator's motion commands outside the safety limits (:func:`~simshear_gym.lab.rig.audit_motion_records`), the
robot time per row by the emulator's motion timing (``robot_row_s``: the durations of every move the emulated arm
executed, the touch-off's and the killed row's redo included, over the rows, plus the protocol's settle and
capture) against the protocol's plan, and the wall time per row (rendering and writing add to the motion).
Writes ``results/collect_real.json`` and ``.png``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.records import write_record
from simshear_gym.machine import machine_info

RANGES = {
    "surface": {"pose_z": [3.0, 5.0], "pose_rz": [-20.0, 20.0], "move_x": [-3.0, 3.0], "move_y": [-3.0, 3.0],
                "move_rz": [-5.0, 5.0]},
    "edge": {"pose_y": [-6.0, 6.0], "pose_z": [3.0, 5.0], "pose_rz": [-170.0, 170.0], "move_x": [-3.0, 3.0],
             "move_y": [-3.0, 3.0], "move_rz": [-5.0, 5.0]},
}
CONFIG = """name = "rehearsal_{contact}"
[replay]
surface_depth_mm = 2.2
edge_y_mm = -0.25
[datasets.placeholder]
contact = "{contact}"
kind = "tap"
image_pattern = "f{{index}}.png"
val_fraction = 0.2
absent = ["move", "pose"]
files = [{{ csv = "none.csv", images = "none" }}]
[collect]
stimulus = "{contact}"
work_origin_base_mm = [300.0, 0.0, -110.0]
rows = {rows}
seed = {seed}
tap_share = 0.5
ranges = {ranges}
"""


def _toml_table(ranges: dict) -> str:
    return "{ " + ", ".join(f"{k} = [{lo}, {hi}]" for k, (lo, hi) in ranges.items()) + " }"


def _rows_written(targets: Path) -> int:
    try:
        return max(0, len(targets.read_text().splitlines()) - 1)
    except OSError:
        return 0


def rehearse(contact: str, rows: int, seed: int, work: Path, timeout_s: float = 3600.0) -> dict:
    """One stimulus's rehearsal with a kill (see the module docstring)."""
    import cv2
    import pandas as pd

    from simshear_gym.lab.collect_protocol import CollectProtocol
    from simshear_gym.lab.collect_real import rehearsal_emulator
    from simshear_gym.lab.experiment import rehearsal_safety
    from simshear_gym.lab.rig import audit_motion_records

    config_path = work / f"{contact}.toml"
    config_path.write_text(CONFIG.format(contact=contact, rows=rows, seed=seed, ranges=_toml_table(RANGES[contact])))
    protocol = CollectProtocol(stimulus=contact, work_origin_base_mm=(300.0, 0.0, -110.0), rows=rows, seed=seed,
                               tap_share=0.5, surface_depth_mm=2.2,
                               ranges={k: tuple(v) for k, v in RANGES[contact].items()})  # the config's [collect]
    _, _, planned_s = protocol.plan()
    emulator = rehearsal_emulator(protocol).start()
    out = work / f"{contact}_set"
    kill_row = int(np.random.default_rng(seed).integers(1, rows - 1))
    try:
        command = [sys.executable, "-m", "simshear_gym.cli", "collect-real", str(config_path), "--robot",
                   f"127.0.0.1:{emulator.dashboard_port},{emulator.motion_port},{emulator.feedback_port}",
                   "--camera", "rehearsal", "--out", str(out)]
        started = time.monotonic()
        child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        while child.poll() is None and _rows_written(out / "targets.csv") < kill_row:
            if time.monotonic() - started > timeout_s:
                child.kill()
                raise RuntimeError(f"collect-real ({contact}) did not reach row {kill_row} in {timeout_s:.0f} s")
            time.sleep(0.01)
        if child.poll() is not None:
            raise RuntimeError(f"collect-real ({contact}) ended before the kill: {child.stderr.read().decode()[-500:]}")
        child.kill()
        child.wait()
        rows_at_kill = _rows_written(out / "targets.csv")
        rerun = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
        if rerun.returncode != 0:
            raise RuntimeError(f"collect-real ({contact}) rerun failed: {rerun.stderr[-500:]}")
        wall_s = time.monotonic() - started
        outside = audit_motion_records(emulator.motion_records(), rehearsal_safety())
        executed = emulator.executed_motions()
    finally:
        emulator.stop()
    table = pd.read_csv(out / "targets.csv")
    names = list(table["sensor_image"])
    files = {p.name for p in (out / "images").iterdir()}
    undecodable = [n for n in names if n in files and (cv2.imread(str(out / "images" / n), 0) is None)]
    outside_ranges = 0
    columns = {"pose_x": "pose_1", "pose_y": "pose_2", "pose_z": "pose_3", "pose_rz": "pose_6", "move_x": "move_1",
               "move_y": "move_2", "move_rz": "move_6"}
    for variable, column in columns.items():
        low, high = protocol.ranges.get(variable, (0.0, 0.0))
        outside_ranges += int(((table[column] < low - 1e-9) | (table[column] > high + 1e-9)).sum())
    label_columns = [f"pose_{i}" for i in range(1, 7)] + [f"move_{i}" for i in range(1, 7)]
    drawn = protocol.draw_rows()
    labels_match = len(table) == len(drawn) and bool(np.allclose(table[label_columns].to_numpy(np.float64),
                                                                 drawn[label_columns].to_numpy(np.float64)))
    row_s = table["robot_time_s"].to_numpy(np.float64)
    motion_s = float(sum(motion.duration_s for motion in executed))
    robot_row_s = motion_s / rows + protocol.settle_s + protocol.frames_per_capture * protocol.frame_period_s
    return {
        "contact": contact, "rows": len(table), "rows_expected": rows, "killed_at_row": rows_at_kill,
        "duplicate_images": len(names) - len(set(names)), "missing_images": len(set(names) - files),
        "stray_files": sorted(files - set(names)), "undecodable_images": len(undecodable),
        "labels_outside_ranges": outside_ranges, "labels_match_protocol_rows": labels_match,
        "emulator_commands": len(emulator.motion_records()),
        "emulator_commands_outside_limits": len(outside), "outside_limits": outside[:10],
        "touch_off": __import__("json").loads((out / "meta.json").read_text())["touch_off"],
        "row_wall_s_median": round(float(np.median(row_s)), 4), "row_wall_s_mean": round(float(row_s.mean()), 4),
        "row_wall_s_p95": round(float(np.percentile(row_s, 95)), 4),
        "planned_row_s_mean": round(float(planned_s.mean()), 4), "wall_s": round(wall_s, 1),
        "executed_motions": len(executed), "executed_motion_s": round(motion_s, 2),
        "robot_row_s": round(robot_row_s, 4),
        "executed_peak_speed_mm_s": round(max((m.peak_speed_mm_s for m in executed), default=0.0), 2),
        "row_wall_s": row_s.round(4).tolist(),
    }


def plot(results: list[dict], path: Path) -> Path:
    plt = pyplot()

    figure, axes = plt.subplots(1, len(results), figsize=(5 * len(results), 3.4), squeeze=False)
    for ax, result in zip(axes[0], results):
        ax.hist(result["row_wall_s"], bins=40, color="tab:blue", alpha=0.8)
        ax.axvline(result["planned_row_s_mean"], color="tab:red", label="planned robot time (mean)")
        ax.axvline(result["robot_row_s"], color="tab:green", label="robot time by the emulator's motions")
        ax.axvline(1.0, color="black", linestyle=":", label="1.0 s")
        ax.set_title(f"{result['contact']}: {result['rows']} rows, killed at row {result['killed_at_row']}")
        ax.set_xlabel("wall time per row on the emulator, s")
        ax.legend(fontsize=7)
    save_figure(figure, path, dpi=90)
    return path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--contacts", nargs="+", choices=sorted(RANGES), default=["surface", "edge"],
                        help="stimuli to rehearse (default both)")
    parser.add_argument("--rows", type=int, default=500, help="rows per stimulus (default 500)")
    parser.add_argument("--seed", type=int, default=0, help="the rows' seed and the kill's row (default 0)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="folder of collect_real.json / .png")
    parser.add_argument("--work", type=Path, default=None, help="folder for the sets (default: a temporary one)")


def run(args: argparse.Namespace) -> int:
    if args.rows < 3:
        raise ValueError(f"--rows must be >= 3 (a kill between the first and the last row), got {args.rows}")
    started = time.monotonic()
    with tempfile.TemporaryDirectory() as scratch:
        work = Path(args.work) if args.work is not None else Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        results = []
        for contact in args.contacts:
            result = rehearse(contact, args.rows, args.seed, work)
            print(f"{contact}: {result['rows']}/{result['rows_expected']} rows (killed at {result['killed_at_row']}),"
                  f" duplicates {result['duplicate_images']}, missing {result['missing_images']}, undecodable "
                  f"{result['undecodable_images']}, labels outside {result['labels_outside_ranges']}, commands "
                  f"outside the limits {result['emulator_commands_outside_limits']} of {result['emulator_commands']};"
                  f" robot time {result['robot_row_s']:.3f} s a row (planned {result['planned_row_s_mean']:.3f}; wall "
                  f"{result['row_wall_s_median']:.3f} median)")
            results.append(result)
    figure = plot(results, args.out / "collect_real.png")
    write_record("simshear evaluate collect-real", add_arguments, args, args.out / "collect_real.json", {
        "machine": machine_info(), "seconds": round(time.monotonic() - started, 1),
        "figure": figure.name, "results": results})
    return 0
