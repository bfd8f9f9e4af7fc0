"""Throughput of the paired collection: (sim image, shear, real image) tuples written per second.

Replays real validation sets end to end (read labels, render, compute shear, write PNGs and targets.csv) into
a temporary folder inside the results folder (so on the disk a collection would write to; a tmpfs or overlay
/tmp measures something else), with 1 and with ``--workers`` processes, and writes
``results/collect_speed.json``.

``--ray ADDRESS`` (``local``: a Ray on this machine) compares the executors instead: ``--rows`` random contacts
per contact type (seed 0), collected in plain processes and as Ray tasks, each with 1 and ``--workers`` workers,
and writes ``<out>/collect_ray.json`` (``results/ablations/collect_ray.json``). The Ray session starts once and
its workers are warmed up before the timed runs (both times recorded apart); every run's set is checked byte for
byte against the plain 1-worker set.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import tempfile
import time
from pathlib import Path

from simshear_gym.data.paths import data_root, real_set_dir
from simshear_gym.evaluate.records import write_record
from simshear_gym.machine import machine_info

# pybullet (via simshear_gym.sim.collect) is imported inside run, so that --help stays light.


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, default=None, help="data root (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--workers", type=int, default=2, help="processes of the parallel run")
    parser.add_argument("--out", type=Path, default=Path("results"), help="results directory")
    parser.add_argument("--ray", metavar="ADDRESS", default=None,
                        help="compare plain processes with Ray at ADDRESS ('local', 'auto', HOST:PORT) on random "
                        "contacts; writes collect_ray.json")
    parser.add_argument("--rows", type=int, default=400, help="random contacts per contact type (with --ray)")


def run(args: argparse.Namespace) -> int:
    if args.workers < 1 or args.rows < 1:
        raise ValueError(f"--workers and --rows must be >= 1, got {args.workers}, {args.rows}")
    if args.ray is not None:
        return run_ray(args)
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
        "machine": machine_info(),
        "goal_tuples_per_s": 500, "paper_reference": "5000 tuples in 60 s (83/s)", "runs": runs,
    }
    write_record("simshear evaluate collect-speed", add_arguments, args, args.out / "collect_speed.json", payload)
    print(f"wrote {args.out / 'collect_speed.json'}")
    return 0


def run_ray(args: argparse.Namespace) -> int:
    """Rows per second of random-contact collection in plain processes and on Ray, at 1 and ``--workers``."""
    from simshear_gym.sim.collect import CollectConfig, random_set
    from simshear_gym.sim.parallel import ray_session

    args.out.mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()
    worker_counts = sorted({1, args.workers})
    runs, warmup = [], {}
    with tempfile.TemporaryDirectory(dir=args.out, prefix=".collect-ray-") as tmp:
        start = time.perf_counter()
        with ray_session(args.ray, num_cpus=args.workers):
            warmup["ray_start_s"] = round(time.perf_counter() - start, 2)
            start = time.perf_counter()  # start the Ray workers (and their imports) before timing them
            random_set("surface", 2 * args.workers, 0, Path(tmp) / "warmup",
                       CollectConfig(workers=args.workers, ray_address=args.ray))
            warmup["ray_warmup_s"] = round(time.perf_counter() - start, 2)
            for contact in ("surface", "edge"):
                reference = None
                for executor in ("processes", "ray"):
                    for workers in worker_counts:
                        out = Path(tmp) / f"{contact}_{executor}_{workers}"
                        config = CollectConfig(workers=workers, ray_address=args.ray if executor == "ray" else None)
                        start = time.perf_counter()
                        rows = random_set(contact, args.rows, 0, out, config)
                        seconds = time.perf_counter() - start
                        reference = reference or _digest(out)
                        runs.append({"contact": contact, "executor": executor, "workers": workers, "rows": rows,
                                     "seconds": round(seconds, 2), "rows_per_s": round(rows / seconds, 1),
                                     "same_bytes_as_processes_1": _digest(out) == reference})
                        print(f"{contact}, {executor}, {workers} worker(s): {rows} rows in {seconds:.2f} s "
                              f"= {rows / seconds:.0f} rows/s")
    payload = {
        "machine": {**machine_info(),
                    "load_average_1_5_15_min_before": [round(x, 2) for x in load_before]},
        "ray_address": args.ray, "source": "random contacts over the tactip331 shear ranges, seed 0",
        **warmup, "runs": runs,
    }
    write_record("simshear evaluate collect-speed", add_arguments, args, args.out / "collect_ray.json", payload)
    print(f"wrote {args.out / 'collect_ray.json'}")
    return 0


def _digest(directory: Path) -> str:
    """sha256 over a set's files (names and bytes), in name order."""
    digest = hashlib.sha256()
    for path in sorted(directory.rglob("*")):
        if path.is_file():
            digest.update(str(path.relative_to(directory)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()
