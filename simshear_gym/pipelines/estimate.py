"""``simshear pipeline estimate CONFIG [--profile P]``: how long a profile's training takes on this machine, before
anything trains.

A profile's budgets are counted in epochs, so its work is fixed: per training step of the run's graph
(:func:`simshear_gym.pipelines.run.training_steps`) the optimiser steps (epochs x batches of its training rows,
from the datasets' label files: :func:`simshear_gym.data.adapter.split_sizes`), a holdout pass per epoch and,
for a GDNN on translations, its rows translated once per generator. What one of each costs is measured here
(:mod:`simshear_gym.train.step_timing`: the package's trainers with the step's settings on random rows of the
real shapes), ``jobs`` probes side by side as the run trains them, started together; steps with the same cost
settings share a probe. The steps are then laid out on ``jobs`` lanes in the order the run starts them
(:func:`simshear_gym.pipelines.stages.order_steps`), which gives the training's wall time.

The probes train on the device the run would (``--device``, else the profile's ``device``): on a GPU machine
``--device cuda`` times each step on the GPU (synchronised) at the step's batch size, its rows on the GPU as the
run keeps them (``data_on_device``), ``jobs`` probes sharing it as the run's steps would; a GDNN's rows are
translated on the GPU there too, as in the run.

The machine's load is measured before the probes (:func:`machine_load`: the CPUs in use over
:data:`BUSY_WINDOW_S` seconds, from ``/proc/stat`` where there is one, else the 1-minute load average): probes
beside other work run slower than the run would on an idle machine, about ``(busy + jobs) / cpus`` times where that
exceeds 1; the estimate says so and gives the idle figure beside it. The load average lags: a minute after a
heavy command it still reads 0.7-1.6 on an idle 2-core machine, which made an estimate just after its own probes
(or a training run) call the machine busy and give an idle figure 1.4x too low (docs/experiments.md,
pipeline_tactip331_fast5).

Not included: the data stages (adapt, collect, random contacts) and the evaluation, about 2 minutes of the
shipped recipe's 136 on the 2-core CPU it was first measured on; a GDNN stopped early by its ``patience_epochs``
takes less. A probe of one setting varies by about 10 % between runs on a shared machine, and the probes read the
epochs of a run at 0.85-1.03x (docs/experiments.md, pipeline_estimate_tactip331_full). Prints a table; ``--json
PATH`` writes it with the command and the machine; ``--compare RUN`` adds a run folder's median epoch times.
"""

from __future__ import annotations

import argparse
import heapq
import json
import multiprocessing
import os
import time
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from simshear_gym.command_line import recorded_command
from simshear_gym.data.adapter import split_sizes
from simshear_gym.io import write_json
from simshear_gym.machine import machine_info
from simshear_gym.pipelines.stages import Step, order_steps
from simshear_gym.tables import add_set_argument

if TYPE_CHECKING:  # the config imports the simulator (pybullet): in run, so that --help stays light
    from simshear_gym.pipelines.config import ExperimentConfig

#: settings that change what a trainer learns but not what a step costs (left out of a probe's key)
FREE_SETTINGS = ("seed", "epochs", "lr", "lr_schedule", "cap_minutes", "max_minutes", "patience_epochs", "holdout",
                 "pose_weight", "pose_variables", "device", "l1_weight", "beta", "dropout", "lr_scaling",
                 "warmup_epochs")


@dataclass(frozen=True)
class StepEstimate:
    """One training step's work and its estimated seconds (``start_s``/``end_s``: on the run's lanes)."""

    name: str
    trainer: str
    rows: int
    epochs: int
    steps_per_epoch: int
    step_s: float
    translate_s: float
    seconds: float
    start_s: float
    end_s: float


BUSY_WINDOW_S = 2.0
"""Seconds over which :func:`busy_cpus_now` counts the CPUs in use."""


def busy_cpus_now(window_s: float = BUSY_WINDOW_S, stat: str = "/proc/stat") -> float | None:
    """CPUs in use (0 to the CPU count) over the next ``window_s`` seconds, from the kernel's CPU time counters
    (``stat``'s first line: user, nice, system, idle, iowait, irq, softirq, steal); None where they cannot be read
    (not Linux)."""
    def counters() -> tuple[int, int] | None:
        try:
            with open(stat) as file:
                fields = [int(value) for value in file.readline().split()[1:9]]
        except (OSError, ValueError):
            return None
        return (sum(fields), fields[3] + fields[4]) if len(fields) == 8 else None  # (total, idle + iowait)

    before = counters()
    if before is None:
        return None
    time.sleep(window_s)
    after = counters()
    if after is None or after[0] <= before[0]:
        return None
    idle_share = (after[1] - before[1]) / (after[0] - before[0])
    return max(0.0, 1.0 - idle_share) * (os.cpu_count() or 1)


def machine_load(jobs: int, busy_cpus: float | None = None, cpus: int | None = None) -> dict:
    """The machine's load as the probes start: ``busy_cpus``, the CPUs in use (:func:`busy_cpus_now` unless given;
    the 1-minute load average where it cannot measure), ``cpus`` (``os.cpu_count`` unless given), the 1-minute
    load average beside them (``load_1min``, for the record: it lags), and ``slowdown``: about how much slower
    ``jobs`` probes run beside that load than on an idle machine, ``max(1, (busy + jobs) / cpus)`` (each process's
    share of the CPUs, when more want one than there are); ``busy``: whether that exceeds 1.1."""
    load_1min = os.getloadavg()[0]
    measured_by = "given"
    if busy_cpus is None:
        busy_cpus = busy_cpus_now()
        measured_by = f"/proc/stat over {BUSY_WINDOW_S:g} s"
        if busy_cpus is None:
            busy_cpus, measured_by = load_1min, "1-minute load average"
    cpus = (os.cpu_count() or 1) if cpus is None else int(cpus)
    slowdown = max(1.0, (float(busy_cpus) + jobs) / cpus)
    return {"busy_cpus": round(float(busy_cpus), 2), "measured_by": measured_by, "load_1min": round(load_1min, 2),
            "cpus": cpus, "jobs": jobs, "slowdown": round(slowdown, 2), "busy": slowdown > 1.1}


def load_note(load: dict, training_wall_min: float) -> str:
    """What the load means for the figure, one line."""
    busy = load.get("busy_cpus", load["load_1min"])  # records written before busy_cpus hold the load average
    if not load["busy"]:
        return (f"machine idle enough ({busy:.2f} of {load['cpus']} CPUs in use, {load['jobs']} probe(s)): "
                "the figure is this machine's")
    return (f"machine busy: {busy:.2f} of {load['cpus']} CPUs in use before the probes, with "
            f"{load['jobs']} probe(s) beside it about {load['slowdown']:.1f}x an idle machine's times; idle, the "
            f"training would take about {training_wall_min / load['slowdown']:.1f} min (run the estimate again when "
            "the machine is idle for a figure that needs no such correction)")


def planned_steps(config: ExperimentConfig, profile: str) -> list[Step]:
    """The run's training steps (their ``work``; their actions are never called)."""
    from simshear_gym.pipelines.run import contacts_of, training_steps

    settings = config.profile(profile)
    paired = {name: {"train": f"paired/{name}"} for name in config.datasets}
    random_sets = {contact: f"random/{contact}" for contact in contacts_of(config)
                   if settings.posenet.random_contacts.get(contact, 0)}
    variables = {contact: contact for contact in contacts_of(config)}
    return training_steps(config, settings, {}, paired, random_sets, variables,
                          ("adapt", "collect", "translator", "posenet"))


def _probe_key(work: dict, image_size_px: int, views: int = 1) -> tuple:
    kept = tuple(sorted((k, v) for k, v in work["settings"].items() if k not in FREE_SETTINGS))
    if work["trainer"] == "translator":
        kept += (("pose", work["settings"].get("pose_weight", 0) > 0),)
    return (work["trainer"], image_size_px, views, kept)


def _translator_probe(settings: dict, image_size_px: int, steps: int, device: str, barrier):
    from simshear_gym.train.step_timing import translation_s_per_row, translator_step_time

    threads = settings.get("threads", 1)
    timed = translator_step_time(settings, image_size_px, steps=steps, threads=threads, ready=barrier.wait,
                                 device=device)
    barrier.wait()
    return timed, translation_s_per_row(settings, image_size_px, threads=threads, device=device)


def _posenet_probe(settings: dict, variables: str, views: int, steps: int, device: str, barrier):
    from simshear_gym.train.step_timing import posenet_step_time

    threads = settings.get("threads", 1)
    return posenet_step_time(settings, variables, views=views, steps=steps, threads=threads, ready=barrier.wait,
                             device=device), 0.0


def _side_by_side(pool, barrier, probe, jobs: int) -> tuple:
    """A probe's (StepTime, translation s per row), averaged over ``jobs`` copies run at once (each starts its
    timed steps, and its translation, when all are ready)."""
    results = pool.map(probe, [barrier] * jobs)
    step_s = sum(r[0].step_s for r in results) / jobs
    holdout = sum(r[0].holdout_s_per_row for r in results) / jobs
    return step_s, holdout, sum(r[1] for r in results) / jobs


def lanes(steps: list[Step], seconds: dict[str, float], jobs: int) -> dict[str, tuple[float, float]]:
    """{step: (start_s, end_s)}: the steps on ``jobs`` lanes, each started as soon as a lane is free and its needs
    are done, the ready ones in :func:`~simshear_gym.pipelines.stages.order_steps`' order (as the run does)."""
    priority = order_steps(steps)
    by_name = {step.name: step for step in steps}
    times: dict[str, tuple[float, float]] = {}
    running: list[tuple[float, str]] = []
    now = 0.0
    while len(times) < len(steps):
        for name in priority:
            if (len(running) < jobs and name not in times
                    and all(need in times and times[need][1] <= now for need in by_name[name].needs)):
                times[name] = (now, now + seconds[name])
                heapq.heappush(running, (now + seconds[name], name))
        now, _ = heapq.heappop(running)
    return times


def estimate(config: ExperimentConfig, root: Path, profile: str, jobs: int | None = None,
             probe_steps: int = 50, device: str | None = None, log=print) -> dict:
    """The profile's training steps with their estimated seconds, and the training's wall time on ``jobs`` lanes
    (None: the profile's), its steps trained on ``device`` (None: the profile's; a GPU's steps, and the translations
    of a GDNN's rows, are probed on it as the run runs them); see the module docstring."""
    from simshear_gym.models.device import check_device_name
    from simshear_gym.models.gdnn import VARIABLE_SETS
    from simshear_gym.pipelines.config import trainer_defaults
    from simshear_gym.train.posenet_config import PosenetTrainConfig
    from simshear_gym.train.translator_config import TranslatorTrainConfig

    settings = config.profile(profile)
    jobs = jobs or settings.jobs
    device = check_device_name(device or settings.device)
    train_rows = {name: split_sizes(dataset, root, name, settings.rows_per_split)["train"]
                  for name, dataset in config.datasets.items()}
    steps = planned_steps(config, profile)
    translator_px, gdnn_px = config.sensor.image_size_px, settings.posenet.setting("image_size_px")
    key_of, probes = {}, {}
    load = machine_load(jobs)  # before the probes add their own
    started = time.perf_counter()
    context = multiprocessing.get_context("spawn")
    with context.Manager() as manager, context.Pool(jobs, maxtasksperchild=1) as pool:
        barrier = manager.Barrier(jobs, timeout=900.0)  # a probe that died breaks it: an error, not a hang
        for step in steps:
            work = step.work
            if work["trainer"] == "translator":
                key_of[step.name] = _probe_key(work, translator_px)
                probe = partial(_translator_probe, work["settings"], translator_px, probe_steps, device)
            else:
                views = max(1, len(work["translators"]))
                key_of[step.name] = _probe_key(work, gdnn_px, views)
                variables = work["contact"] if work["contact"] in VARIABLE_SETS else "surface"  # same cost
                probe = partial(_posenet_probe, work["settings"], variables, views, probe_steps, device)
            if key_of[step.name] not in probes:
                log(f"probing {step.name} ({work['trainer']}, {jobs} side by side)")
                probes[key_of[step.name]] = _side_by_side(pool, barrier, probe, jobs)
    probe_s = time.perf_counter() - started

    planned = {}
    for step in steps:
        work = step.work
        rows = sum(train_rows[name] for name in work["datasets"]) + work.get("random_rows", 0)
        step_s, holdout_s, _ = probes[key_of[step.name]]
        if work["trainer"] == "translator":
            config_class, last_batch, translate_s = TranslatorTrainConfig, 1, 0.0  # no last batch of one row
        else:
            config_class, last_batch = PosenetTrainConfig, 0
            translate_s = sum(rows * probes[key_of[name]][2] for name in work["translators"])
        batch = work["settings"].get("batch_size", trainer_defaults(config_class)["batch_size"])
        holdout = max(1, round(work["settings"].get("holdout", trainer_defaults(config_class)["holdout"]) * rows))
        per_epoch = len(range(0, rows - holdout - last_batch, batch))
        epochs = work["settings"]["epochs"]
        planned[step.name] = {"name": step.name, "trainer": work["trainer"], "rows": rows, "epochs": epochs,
                              "steps_per_epoch": per_epoch, "step_s": round(step_s, 4),
                              "translate_s": round(translate_s, 3),
                              "seconds": epochs * (per_epoch * step_s + holdout * holdout_s) + translate_s}
    laid = lanes(steps, {name: plan["seconds"] for name, plan in planned.items()}, jobs)
    estimates = [StepEstimate(**(planned[name] | {"seconds": round(planned[name]["seconds"], 3)}),
                              start_s=round(laid[name][0], 3), end_s=round(laid[name][1], 3))
                 for name in sorted(laid, key=lambda n: laid[n])]
    wall_s = max(end for _, end in laid.values())
    return {"config": str(config.path), "sensor": config.name, "profile": profile, "jobs": jobs, "device": device,
            "probe_s": round(probe_s, 1), "training_wall_min": round(wall_s / 60, 1),
            "lane_busy_min": round(sum(plan["seconds"] for plan in planned.values()) / 60, 1),
            "load": load, "training_wall_min_if_idle": round(wall_s / 60 / load["slowdown"], 1),
            "steps": [asdict(e) for e in estimates]}


def measured_epochs(result: dict, run: Path) -> list[dict]:
    """Each estimated step that ``run`` (a pipeline run folder) trained at least one epoch of, with the median
    wall time of its epochs there (its ``run/history.json``; the median, so that an epoch slowed by other work
    on the machine counts little) against the estimate's time per epoch."""
    rows = []
    for step in result["steps"]:
        histories = sorted(run.glob(f"{step['name']}/*/run/history.json"), key=lambda p: p.stat().st_mtime)
        if not histories:
            continue
        elapsed = [epoch["elapsed_s"] for epoch in json.loads(histories[-1].read_text())["epochs"]
                   if not epoch.get("partial_epoch")]
        if not elapsed:
            continue
        measured = float(np.median(np.diff([0.0, *elapsed])))
        estimated = (step["seconds"] - step["translate_s"]) / step["epochs"]
        rows.append({"name": step["name"], "epochs_measured": len(elapsed), "measured_epoch_s": round(measured, 1),
                     "estimated_epoch_s": round(estimated, 1),
                     "estimate_over_measured": round(estimated / measured, 3)})
    return rows


def format_estimate(result: dict) -> str:
    lines = [f"{'step':32s} {'rows':>6s} {'epochs':>6s} {'steps/ep':>8s} {'s/step':>7s} {'min':>6s} "
             f"{'start-end (min)':>16s}"]
    for s in result["steps"]:
        lines.append(f"{s['name']:32s} {s['rows']:6d} {s['epochs']:6d} {s['steps_per_epoch']:8d} "
                     f"{s['step_s']:7.3f} {s['seconds'] / 60:6.1f} {s['start_s'] / 60:7.1f}-{s['end_s'] / 60:<8.1f}")
    for row in result.get("measured", []):
        lines.append(f"  {row['name']}: {row['estimated_epoch_s']} s per epoch estimated, {row['measured_epoch_s']} s "
                     f"measured (median of {row['epochs_measured']} epochs): {row['estimate_over_measured']:.2f}x")
    lines.append(f"{result['sensor']} profile {result['profile']}: training about {result['training_wall_min']} min "
                 f"on {result['jobs']} lane(s) of this machine (device {result.get('device', 'cpu')}; "
                 f"{result['lane_busy_min']} lane-min of steps), plus "
                 f"the data stages and the evaluation (a few minutes)")
    if "load" in result:
        lines.append(load_note(result["load"], result["training_wall_min"]))
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------- command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    from simshear_gym.models.device import DEVICES

    parser.add_argument("config", type=Path, help="experiment config (TOML), e.g. configs/tactip331.toml")
    add_set_argument(parser)
    parser.add_argument("--profile", default="quick", help="the profile to estimate: smoke, quick or full")
    parser.add_argument("--data", type=Path, default=None,
                        help="data root the config's paths are relative to (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--jobs", type=int, default=None,
                        help="training steps side by side (default: the profile's jobs)")
    parser.add_argument("--probe-steps", type=int, default=50, help="timed optimiser steps per probe (default 50)")
    parser.add_argument("--device", choices=DEVICES, default=None,
                        help="where the training steps train, probed there (default: the profile's device)")
    parser.add_argument("--json", type=Path, default=None, help="also write the estimate to this JSON file")
    parser.add_argument("--compare", type=Path, default=None, metavar="RUN",
                        help="a pipeline run folder of this profile: its steps' epoch times against the estimate's")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.pipelines.run import config_and_root

    for name in ("jobs", "probe_steps"):
        value = getattr(args, name)
        if value is not None and value < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be a positive integer, got {value!r}")
    config, root = config_and_root(args)
    if args.compare is not None and not args.compare.is_dir():
        raise FileNotFoundError(f"--compare {args.compare}: no such run folder")
    result = estimate(config, root, args.profile, args.jobs, args.probe_steps, args.device)
    if args.compare is not None:
        result["compared_with"] = str(args.compare)
        result["measured"] = measured_epochs(result, args.compare)
    print(format_estimate(result))
    if args.json is not None:
        write_json(args.json, {"command": recorded_command("simshear pipeline estimate", add_arguments, args),
                               "machine": machine_info(), **result})
        print(f"wrote {args.json}")
    return 0

