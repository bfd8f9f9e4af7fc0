"""``simshear collect-real CONFIG --robot HOST[:PORTS] --camera SRC --out DIR``: record a sensor's tap and shear
data set with the MG400 from its config's ``[collect]`` protocol (:mod:`simshear_gym.lab.collect_real`);
``--rehearsal``: on an emulated MG400 and a camera rendering the configured face; ``--dry-run``: the plan and the
robot time, nothing moves. A rerun of the same command continues at the next row."""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from simshear_gym.io import atomic_write
from simshear_gym.lab.collect_real import (
    STUB,
    TARGETS,
    Rehearsal,
    check_protocol,
    collect,
    config_stub,
    connect,
    plan_text,
    rehearsal_camera,
)
from simshear_gym.tables import add_set_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", type=Path, help="the sensor's config (TOML) with a [collect] table")
    add_set_argument(parser)
    parser.add_argument("--robot", default=None, metavar="HOST[:PORTS]",
                        help="the MG400: HOST or HOST:DASHBOARD,MOTION,FEEDBACK (not with --rehearsal)")
    parser.add_argument("--camera", default=None,
                        help="camera device index, video file or image folder; 'rehearsal': the configured stimulus "
                        "rendered from the arm's feedback (an emulator: `simshear mg400-emulator`)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (a rerun continues there)")
    parser.add_argument("--rehearsal", action="store_true",
                        help="no hardware: an emulated MG400 and a camera rendering the configured stimulus")
    parser.add_argument("--dry-run", action="store_true",
                        help="check the protocol and print the plan and the robot time; nothing moves")
    parser.add_argument("--rows", type=int, default=None, help="record only the first N rows of the protocol")



def run(args: argparse.Namespace) -> int:
    from simshear_gym.lab.endpoints import ArmEndpoint
    from simshear_gym.lab.experiment import rehearsal_safety
    from simshear_gym.pipelines.config import load_config
    from simshear_gym.real.camera import CameraSource, default_config, preprocess
    from simshear_gym.real.safety import SafetyConfig
    from simshear_gym.tables import read_toml

    config = load_config(args.config, args.settings)
    if config.collect is None:
        raise ValueError(f"{args.config}: no [collect] table (the data-collection protocol; configs/README.md)")
    protocol = config.collect
    if args.rows is not None:
        from dataclasses import replace

        protocol = replace(protocol, rows=args.rows)
    safety = rehearsal_safety() if args.rehearsal or args.camera == "rehearsal" else SafetyConfig()
    times = check_protocol(protocol, safety)
    print(plan_text(protocol, times))
    if args.dry_run:
        return 0
    if args.out is None or (not args.rehearsal and (args.robot is None or args.camera is None)):
        raise ValueError("give --out, and --robot and --camera (or --rehearsal), or --dry-run")
    layout = default_config()
    raw = read_toml(args.config)
    tables = {key: raw.get(key, {}) for key in ("sensor", "replay")}

    def show(done: int, total: int, row_s: float) -> None:
        print(f"\rrow {done}/{total}  {row_s:.2f} s/row  ETA {(total - done) * row_s / 60.0:.1f} min", end="",
              flush=True)

    def record(client, camera) -> dict:
        return collect(protocol, client, camera, args.out, lambda frame: preprocess(frame, layout),
                       {"config": str(args.config), "sensor": config.name}, progress=show)

    if args.rehearsal:
        with Rehearsal(protocol, config.replay) as rig, connect(rig.endpoint, safety) as client:
            summary = record(client, rig.camera)
    elif args.camera == "rehearsal":  # an arm (or an emulator elsewhere) and the camera rendered from its feedback
        with connect(ArmEndpoint.parse(args.robot, "--robot"), safety) as client:
            with rehearsal_camera(protocol, config.replay, client.measured_pose) as camera:
                summary = record(client, camera)
    else:
        with CameraSource(args.camera) as camera, connect(ArmEndpoint.parse(args.robot, "--robot"), safety) as client:
            summary = record(client, camera)
    print()
    rows = pd.read_csv(Path(args.out) / TARGETS)
    stub = config_stub(f"{config.name}_collected", protocol, tables, Path(args.out).resolve(), rows)
    atomic_write(Path(args.out) / STUB, lambda path: Path(path).write_text(stub))
    print(f"{summary['rows']}/{summary['total']} rows in {args.out} (resumed at row {summary['resumed_at']}; "
          f"{summary['row_s_mean']} s a row, planned {summary['planned_row_s_mean']} s); config: {args.out}/{STUB}")
    return 0
