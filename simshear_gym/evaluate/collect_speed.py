"""Throughput of the paired collection: (sim image, shear, real image) tuples written per second.

Replays real validation sets end to end (read labels, render, compute shear, write PNGs and targets.csv) into
a temporary folder inside the results folder (so on the disk a collection would write to; a tmpfs or overlay
/tmp measures something else), with 1 and with ``--workers`` processes, and writes
``results/collect_speed.json``.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

from simshear_gym.data.paths import data_root, real_set_dir
from simshear_gym.io import write_json

# pybullet (via simshear_gym.sim.collect) is imported inside run, so that --help stays light.


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, default=None, help="data root (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--workers", type=int, default=2, help="processes of the parallel run")
    parser.add_argument("--out", type=Path, default=Path("results"), help="results directory")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.sim.collect import CollectConfig, replay_set

    root = data_root(args.data)
    runs = []
    for workers in sorted({1, args.workers}):
        for contact in ("surface", "edge"):
            real_dir = real_set_dir(root, contact, "shear", "val")
            args.out.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=args.out, prefix=".collect-speed-") as tmp:
                start = time.perf_counter()
                rows = replay_set(real_dir, Path(tmp) / "paired", CollectConfig(workers=workers), root)
                seconds = time.perf_counter() - start
            runs.append({"contact": contact, "workers": workers, "rows": rows, "seconds": round(seconds, 2),
                         "tuples_per_s": round(rows / seconds, 1)})
            print(f"{contact} shear val, {workers} worker(s): {rows} tuples in {seconds:.2f} s "
                  f"= {rows / seconds:.0f} tuples/s")
    payload = {
        "command": f"simshear evaluate collect-speed --workers {args.workers}",
        "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine()},
        "goal_tuples_per_s": 500, "paper_reference": "5000 tuples in 60 s (83/s)", "runs": runs,
    }
    write_json(args.out / "collect_speed.json", payload)
    print(f"wrote {args.out / 'collect_speed.json'}")
    return 0
