"""``simshear collect``: render paired sets from real sets or random contacts (engine:
:mod:`simshear_gym.sim.collect`; format: :mod:`simshear_gym.data.paired`).

``simshear collect --replay DIR [DIR ...] --out OUT`` and ``simshear collect --replay-all --out OUT`` (the eight
tactip331 sets) replay real sets; ``simshear collect --task surface|edge --n N --seed S --out OUT`` draws
random contacts over the real sets' ranges. ``--ray ADDRESS`` renders on Ray (``local``: a Ray on this machine;
``auto`` or ``HOST:PORT``: a running cluster, see docs/scaling_ray.md) instead of plain processes; the rows are
the same either way.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from pathlib import Path

from simshear_gym.data.paths import SPLITS, TACTIP331_TASKS, data_root, real_set_dir
from simshear_gym.tables import add_set_argument

# pybullet (via simshear_gym.sim) is imported inside run, so that `simshear collect --help` stays light.


# ----------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--replay", nargs="+", type=Path, metavar="REAL_SET_DIR",
                        help="real set directories to replay (images/ + targets.csv)")
    source.add_argument("--replay-all", action="store_true",
                        help="replay the eight tactip331 sets under the data root into OUT/<contact>_<kind>/<split>")
    source.add_argument("--task", choices=("surface", "edge"), help="random contacts of this type")
    source.add_argument("--protocol", type=Path, metavar="CONFIG",
                        help="the rows of a sensor config's [collect] table, rendered with its [sensor] and [replay] "
                        "(the same rows, in the same order, as `simshear collect-real CONFIG` records)")
    add_set_argument(parser)  # with --protocol
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--n", type=int, default=5000, help="number of random contacts (--task)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random contacts (--task)")
    parser.add_argument("--contact", choices=("surface", "edge"), help="contact type of --replay sets "
                        "(default: read from the path)")
    parser.add_argument("--data", type=Path, default=None, help="data root (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--image-size", type=int, default=128, choices=(64, 128, 256),
                        help="side of the rendered sim images in px (default 128)")
    parser.add_argument("--workers", type=int, default=2,
                        help="rendering processes (with --ray: Ray tasks, and a local Ray's CPUs)")
    parser.add_argument("--ray", metavar="ADDRESS", default=None,
                        help="render as Ray tasks: 'local' (a Ray on this machine), 'auto' (the cluster `ray start` "
                        "joined here) or a head's HOST:PORT; needs the ray extra (default: plain processes)")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.sim.collect import CollectConfig, random_set, replay_set
    from simshear_gym.sim.parallel import ray_session
    from simshear_gym.sim.tactip import TacTipConfig

    if args.settings and args.protocol is None:
        raise ValueError("--set overrides a config's settings: it goes with --protocol CONFIG")

    config = CollectConfig(tactip=TacTipConfig(image_size_px=args.image_size), workers=args.workers,
                           ray_address=args.ray)
    start = time.perf_counter()
    if args.protocol:
        return _run_protocol(args, start)
    if args.task:
        jobs = [(f"random {args.task}", lambda: random_set(args.task, args.n, args.seed, args.out, config))]
    else:
        root = data_root(args.data) if (args.replay_all or args.data) else _optional_root()
        if args.replay_all:
            pairs = [(real_set_dir(root, contact, kind, split), args.out / f"{contact}_{kind}" / split)
                     for contact, kind in TACTIP331_TASKS for split in SPLITS]
        elif len(args.replay) == 1:
            pairs = [(args.replay[0], args.out)]
        else:
            pairs = [(d, args.out / "_".join(Path(d).resolve().parts[-3:])) for d in args.replay]
        jobs = [(str(real), lambda r=real, o=out: replay_set(r, o, config, root, args.contact)) for real, out in pairs]
    total = 0
    # one Ray session for all the sets (a local Ray starts once)
    with ray_session(args.ray, num_cpus=args.workers) if args.ray else contextlib.nullcontext():
        for name, job in jobs:
            rows = job()
            total += rows
            print(f"{name}: {rows} rows")
    elapsed = time.perf_counter() - start
    print(f"wrote {total} paired rows to {args.out} in {elapsed:.1f} s ({total / max(elapsed, 1e-9):.0f} rows/s)")
    return 0


def _optional_root() -> Path | None:
    try:
        return data_root()
    except FileNotFoundError:
        return None


def _run_protocol(args: argparse.Namespace, start: float) -> int:
    """``--protocol CONFIG``: render the rows of its ``[collect]`` table into OUT."""
    from simshear_gym.pipelines.config import load_config
    from simshear_gym.sim.collect import CollectConfig, labelled_set

    config = load_config(args.protocol, args.settings)
    if config.collect is None:
        raise ValueError(f"{args.protocol}: no [collect] table (the data-collection protocol; configs/README.md)")
    protocol = config.collect
    rows = protocol.draw_rows()
    labels = rows.drop(columns="kind").to_numpy()
    collect_config = CollectConfig(tactip=config.sensor, geometry=config.replay, workers=args.workers)
    n = labelled_set(protocol.stimulus, labels, args.out, collect_config, "protocol",
                     {"config": str(args.protocol), "sensor": config.name, "seed": protocol.seed})
    print(f"protocol of {args.protocol}: {n} rows -> {args.out} ({time.perf_counter() - start:.1f} s)")
    return 0
