"""``simshear pipeline sweep CONFIG --real-rows 250 500 1000 2000 all [--profile P]``: how many real rows the chain
needs.

For each budget N (real training rows per dataset; ``all``: every training row of the profile), per contact type:

- ``rows/<dataset>``: N rows of each paired training set, drawn at random by one seeded permutation (a smaller
  budget's rows among a larger one's: the first N rows of a collection of random poses; ``--rows-from first``: the
  set's first N, for a set in collection order; a published set may be sorted by a label, as tactip331's edge sets
  are by the edge angle), a set of its own, cached by its content; its images link to the full set's;
- the chain: a shPix2pix and the profile's pool generators trained on those N pairs (a pool generator with the
  pose-consistency loss read by the GDNN on the N real images: a lab with N rows has no other reader), and a GDNN
  on their translations of the sim renders of *every* training row (sim contacts cost no robot time; plus the
  profile's random sim contacts);
- beside it a GDNN trained on the same N real images, and the reference: a GDNN on all real training rows;
- the evaluation on every dataset's complete real validation rows (the same for every budget): MAE per read
  variable for the three GDNNs, translation MAPE against nearest-label retrieval from the same N rows.

Every step is a cached stage of the run folder (:mod:`simshear_gym.pipelines.stages`): the budget ``all`` and the
reference share their stages with ``simshear pipeline run`` in the same folder. The sweep leaves out the profile's
pix2pix and baseline GDNNs. Budgets are the profile's epochs (fewer rows: fewer optimiser steps, recorded);
``--scale-epochs CAP`` multiplies the epochs of the models trained on N rows by all/N, at most CAP.

Writes, per contact type, a record (``<record-prefix>_<contact>.json``: the command, what produced it, per budget
rows, robot minutes at the collection rate, MAE per variable, MAPE, epochs and optimiser steps) and its figure
(``.png``: MAE against rows on a log axis, robot minutes on a second axis).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from simshear_gym.command_line import recorded_command
from simshear_gym.io import recorded_path, write_json
from simshear_gym.pipelines.stages import StageRunner, file_fingerprint, run_steps
from simshear_gym.tables import add_set_argument

ALL = "all"
ROWS_FROM = ("random", "first")
"""Which N rows of a set a budget takes (:func:`subset_rows`)."""
SUBSET_SEED = 0
PAPER_ROWS_PER_TASK = 5000
PAPER_ROBOT_MINUTES_PER_TASK = 130.0
ROBOT_S_PER_ROW = PAPER_ROBOT_MINUTES_PER_TASK * 60.0 / PAPER_ROWS_PER_TASK
"""The collection rate: the paper's 5000 real training tuples per task in 130 robot-minutes (1.56 s a row)."""

SOURCES = {"chain": "shpix2pix", "real_rows": "real_rows", "reference": "real"}
"""The record's names of the three GDNNs -> their names in the evaluation."""


@dataclass(frozen=True)
class Budget:
    """A budget: ``rows`` real training rows per dataset (None: all of them)."""

    rows: int | None

    @property
    def label(self) -> str:
        return ALL if self.rows is None else str(self.rows)


def parse_budgets(values: list[str]) -> tuple[Budget, ...]:
    """``--real-rows`` values (integers >= 1 or ``all``) as budgets in increasing order; a bad or repeated value is a
    ValueError naming it."""
    if not values:
        raise ValueError("--real-rows: no budget given; expected numbers of rows (integers >= 1) and/or 'all'")
    budgets = []
    for value in values:
        text = str(value).strip().lower()
        if text == ALL:
            budgets.append(Budget(None))
            continue
        try:
            rows = int(text)
        except ValueError:
            rows = 0  # not a number: no more a budget than a number below 1
        if rows < 1:
            raise ValueError(f"--real-rows: {value!r} is not a budget; expected a number of real training rows "
                             f"per dataset (an integer >= 1) or 'all'")
        budgets.append(Budget(rows))
    labels = [budget.label for budget in budgets]
    repeated = sorted({label for label in labels if labels.count(label) > 1})
    if repeated:
        raise ValueError(f"--real-rows: {repeated[0]!r} is given more than once; expected each budget once")
    return tuple(sorted(budgets, key=lambda b: math.inf if b.rows is None else b.rows))


def check_budgets(budgets: tuple[Budget, ...], train_rows: dict[str, int]) -> None:
    """Every budget must leave some rows out of every dataset's training split (``all`` takes them all)."""
    for budget in budgets:
        if budget.rows is None:
            continue
        for name, rows in train_rows.items():
            if budget.rows >= rows:
                raise ValueError(f"--real-rows: {budget.rows} is not below the {rows} training rows of dataset "
                                 f"{name!r}; expected budgets below {min(train_rows.values())} (or 'all' for every "
                                 "row)")


def epoch_scale(budget: Budget, rows: int, all_rows: int, cap: float | None) -> float:
    """The factor on the epochs of a model trained on ``rows`` of ``all_rows``: all/rows, at most ``cap`` (None: 1)."""
    if cap is None or budget.rows is None:
        return 1.0
    return max(1.0, min(all_rows / rows, cap))


def scaled(epochs: int, factor: float) -> int:
    return max(1, round(epochs * factor))


def subset_rows(count: int, rows: int, order: str) -> np.ndarray:
    """The indices of a budget's ``rows`` of a set of ``count`` rows, in the set's order: the first ones
    (``order`` "first"), or the first of one fixed permutation ("random", seed :data:`SUBSET_SEED`: a lab's first
    N rows of a collection in random order; a smaller budget's rows are among a larger one's)."""
    if order not in ROWS_FROM:
        raise ValueError(f"--rows-from: {order!r}; expected one of {list(ROWS_FROM)}")
    if order == "first":
        return np.arange(min(rows, count))
    return np.sort(np.random.default_rng(SUBSET_SEED).permutation(count)[:rows])


def write_rows(runner: StageRunner, name: str, source: str, rows: int, order: str = "random") -> str:
    """``rows/<name>``: ``rows`` rows of the paired set ``source`` (relative to the run folder; which ones:
    :func:`subset_rows`) as a set of its own (its ``targets.csv`` cut, its ``meta.json`` as it was, ``images/`` a
    link to the full set's); cached by the source's labels, the row count and the order. Returns its path relative
    to the run folder."""
    full = runner.root / source
    key = {"source": source, "rows": rows, "targets": file_fingerprint([full / "targets.csv"]),
           **({"order": order, "seed": SUBSET_SEED} if order != "first" else {})}

    def work(folder: Path) -> dict:
        out = folder / "set"
        out.mkdir(parents=True, exist_ok=True)
        targets = pd.read_csv(full / "targets.csv")
        targets.iloc[subset_rows(len(targets), rows, order)].to_csv(out / "targets.csv", index=False)
        if (full / "meta.json").is_file():
            (out / "meta.json").write_text((full / "meta.json").read_text())
        link = out / "images"
        if not link.exists():
            os.symlink(os.path.relpath(full / "images", out), link)
        return {"outputs": {"set": runner.relative(out)}, "metrics": {"rows": int(min(rows, len(targets)))}}

    return runner.run(f"rows/{name}", key, work).outputs["set"]


def budget_steps(config, profile, budget: Budget, paired: dict, subsets: dict, random_sets: dict, variables: dict,
                 device: str, cap: float | None, train_rows: dict[str, int]) -> tuple[list, dict]:
    """The steps of one budget (:func:`.stages.run_steps`): per contact type its shPix2pix on the N pairs, the GDNN
    on its translations of every sim render, the GDNN on the N real images and the reference; with the epochs each
    trains ({step: epochs})."""
    from simshear_gym.pipelines.run import arch_step, chain_step, contacts_of, gdnn_step, pool_step

    steps, epochs = [], {}
    for contact, names in contacts_of(config).items():
        all_sets = [paired[name]["train"] for name in names]
        budget_sets = [subsets[name] for name in names]
        used = sum(min(budget.rows or train_rows[name], train_rows[name]) for name in names)
        factor = epoch_scale(budget, used, sum(train_rows[name] for name in names), cap)
        translator = profile.translator
        translator = translator.with_epochs(scaled(translator.epochs_for(contact), factor))
        reader = profile.posenet
        real_rows = reader.with_epochs(scaled(reader.epochs_for(contact), factor))
        steps.append(arch_step(config, translator, contact, "shpix2pix", names, budget_sets, device))
        real_rows_name = f"posenet/{contact}_real_rows" if budget.rows is not None else f"posenet/{contact}_real"
        pool = []
        for generator in profile.pool_for(contact):
            if generator.reader_seed:
                raise ValueError(f"pool generator {generator.name!r}: reader_seed {generator.reader_seed} is not "
                                 "swept (a budget's generators read with the GDNN on its N real images); expected "
                                 "reader_seed 0")
            own = generator.overrides.get("epochs")
            if own is not None:
                generator = replace(generator, overrides={**generator.overrides, "epochs": scaled(own, factor)})
            steps.append(pool_step(config, translator, contact, names, budget_sets, generator, device,
                                   reader=real_rows_name))
            pool.append(generator)
        steps.append(chain_step(config, reader, contact, names, all_sets, random_sets, variables[contact], pool,
                                device))
        if budget.rows is not None:  # at 'all' the GDNN on the N real images is the reference
            steps.append(gdnn_step(config, real_rows, contact, "real", names, budget_sets, variables[contact],
                                   device=device, name=real_rows_name))
        steps.append(gdnn_step(config, reader, contact, "real", names, all_sets, variables[contact], device=device))
        chain = reader.epochs_for(contact)
        epochs[contact] = {"factor": factor, "translator": translator.epochs_for(contact), "chain": chain,
                           "real_rows": real_rows.epochs_for(contact) if budget.rows is not None else chain,
                           "reference": chain}
    return steps, epochs


def sweep_profile(config, profile_name: str):
    """The profile as the sweep trains it: its shPix2pix and pool generators per contact type (no pix2pix or
    baseline GDNNs)."""
    profile = config.profile(profile_name)
    return replace(profile, translator=replace(profile.translator, archs=("shpix2pix",)),
                   posenet=replace(profile.posenet, baselines=()))


def run_sweep(config, out: Path, root: Path, profile_name: str, budgets: tuple[Budget, ...], *,
              scale_cap: float | None = None, workers: int = 2, jobs: int | None = None,
              device: str | None = None, rows_from: str = "random", log=print) -> dict:
    """Train and evaluate every budget (each step cached in ``out``); returns the records' common figures (wall
    time, load, how many stages ran now or were cached) and {contact: its budgets}."""
    from simshear_gym.models.device import check_device_name
    from simshear_gym.pipelines.run import (
        contacts_of,
        git_commit,
        stage_adapt,
        stage_collect,
        stage_random,
        variables_for,
    )

    if scale_cap is not None and not (scale_cap >= 1.0):
        raise ValueError(f"--scale-epochs: {scale_cap!r} is not a cap; expected a factor >= 1 (the epochs of a model "
                         "on N rows times all/N, at most this)")
    profile = sweep_profile(config, profile_name)
    jobs = jobs or profile.jobs
    device = check_device_name(device or profile.device)
    out.mkdir(parents=True, exist_ok=True)
    runner = StageRunner(out, log=log)
    commit, started, load_before = git_commit(), time.perf_counter(), os.getloadavg()[0]
    adapted = stage_adapt(runner, config, root, profile.rows_per_split)
    paired = stage_collect(runner, config, adapted, workers)
    train_rows, val_rows = ({name: len(pd.read_csv(runner.root / splits[split] / "targets.csv"))
                             for name, splits in paired.items()} for split in ("train", "val"))
    check_budgets(budgets, train_rows)
    variables = {contact: variables_for(config, names, adapted, runner.root)
                 for contact, names in contacts_of(config).items()}
    random_sets = stage_random(runner, config, profile, adapted, workers)
    results: dict[str, list] = {contact: [] for contact in contacts_of(config)}
    trained: list = []
    for budget in budgets:
        log(f"[sweep] budget {budget.label} real rows per dataset")
        subsets = {name: (paired[name]["train"] if budget.rows is None
                          else write_rows(runner, name, paired[name]["train"], budget.rows, rows_from))
                   for name in paired}
        steps, epochs = budget_steps(config, profile, budget, paired, subsets, random_sets, variables, device,
                                     scale_cap, train_rows)
        done = run_steps(steps, out, jobs, log=log)
        trained += list(done.values())
        evaluation = evaluate_budget(runner, config, profile, adapted, paired, subsets, variables, done)
        for contact, names in contacts_of(config).items():
            results[contact].append(budget_entry(budget, names, train_rows, evaluation, epochs[contact], done,
                                                 contact))
    return {"commit": commit, "wall_s": round(time.perf_counter() - started, 1), "device": device, "jobs": jobs,
            "load_1min": {"start": round(load_before, 2), "end": round(os.getloadavg()[0], 2)},
            "stages": {"ran": sum(r.ran for r in runner.results + trained),
                       "cached": sum(not r.ran for r in runner.results + trained)},
            "train_rows": train_rows, "val_rows": val_rows, "variables": variables, "budgets": results}


def evaluate_budget(runner: StageRunner, config, profile, adapted: dict, paired: dict, subsets: dict,
                    variables: dict, done: dict) -> dict:
    """The pipeline's evaluation (:func:`~simshear_gym.pipelines.evaluation.evaluate_sensor`) of one budget's
    models on every dataset's complete validation rows; retrieval from the budget's training rows."""
    from simshear_gym.pipelines.run import contacts_of, evaluation_stage

    contacts = contacts_of(config)
    translators = {contact: {"shpix2pix": done[f"translator/{contact}_shpix2pix"].outputs["weights"]}
                   for contact in contacts}
    models = {contact: {source: done[step_of(contact, source, done)].outputs["weights"]
                        for source in ("real", "shpix2pix", "real_rows")} for contact in contacts}
    budget_paired = {name: {"train": subsets[name], "val": paired[name]["val"]} for name in paired}
    key = {"paired": budget_paired, "translators": translators, "models": models, "variables": variables,
           "eval_rows": profile.eval_rows}
    result = evaluation_stage(runner, "sweep_evaluate", key, config, adapted, budget_paired, translators,
                              {"models": models, "variables": variables}, profile.eval_rows)
    return json.loads((runner.root / result.outputs["evaluation"]).read_text())


def step_of(contact: str, source: str, done: dict) -> str:
    """The step that trained a contact type's GDNN ``source`` (at 'all': the reference is the one on N rows)."""
    name = f"posenet/{contact}_{source}"
    return name if name in done else f"posenet/{contact}_real"


def budget_entry(budget: Budget, names: list[str], train_rows: dict[str, int], evaluation: dict, epochs: dict,
                 done: dict, contact: str) -> dict:
    """One budget's figures for a contact type's record."""
    rows = {name: train_rows[name] if budget.rows is None else budget.rows for name in names}
    trained = {"translator": f"translator/{contact}_shpix2pix", "chain": f"posenet/{contact}_shpix2pix",
               "real_rows": step_of(contact, "real_rows", done), "reference": f"posenet/{contact}_real"}
    steps = {label: done[step].record["metrics"].get("steps") for label, step in trained.items()}
    wall_s = {label: done[step].record["wall_s"] for label, step in trained.items()}
    datasets = {}
    for name in names:
        readings = evaluation["posenet"][name]
        translation = evaluation["translation"][name]
        mae = {}
        for label, source in SOURCES.items():
            mae[label] = {variable: figures["mae"] for variable, figures in readings[source].items()
                          if variable != "mean_nll"}
        datasets[name] = {
            "val_rows": translation["rows"], "mae": mae, "chance_mae": {
                variable: figures["chance_mae"] for variable, figures in readings["real"].items()
                if variable != "mean_nll"},
            "read_by_reference": readings.get("read_by_real", []),
            **{metric: {"translator": translation["shpix2pix"][metric],
                        "retrieval": translation["nearest-label retrieval"][metric]} for metric in ("mape", "ssim")}}
    return {"budget": budget.label, "rows_per_dataset": rows,
            "robot_minutes": round(sum(rows.values()) * ROBOT_S_PER_ROW / 60.0, 2),
            "epochs": epochs, "optimiser_steps": steps, "stage_wall_s": wall_s, "datasets": datasets}


# ------------------------------------------------------------------------------------------------ figure
def plot_contact(record: dict, path: Path) -> None:
    """MAE per variable against real rows (log axis, robot minutes above) for the chain, the GDNN on N real images
    and the reference; one panel per dataset and variable the reference reads, and one of translation MAPE against
    retrieval."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullLocator

    entries = record["budgets"]
    xs = [sum(e["rows_per_dataset"].values()) / len(e["rows_per_dataset"]) for e in entries]
    panels = [(name, variable) for name in entries[0]["datasets"]  # the variables the reference reads
              for variable in entries[0]["datasets"][name]["read_by_reference"]]
    panels += [(name, None) for name in entries[0]["datasets"]]
    columns = min(4, len(panels))
    rows = math.ceil(len(panels) / columns)
    figure, axes = plt.subplots(rows, columns, figsize=(3.6 * columns, 3.0 * rows), squeeze=False)
    styles = {"chain": ("C0", "o-", "GDNN on translated sim"), "real_rows": ("C1", "s-", "GDNN on the N real"),
              "reference": ("C2", "--", "reference: all real rows")}
    for axis, (name, variable) in zip(axes.flat, panels):
        if variable is None:
            axis.plot(xs, [e["datasets"][name]["mape"]["translator"] for e in entries], "o-", color="C0",
                      label="shPix2pix")
            axis.plot(xs, [e["datasets"][name]["mape"]["retrieval"] for e in entries], "s-", color="C3",
                      label="nearest-label retrieval")
            axis.set_title(f"{name}: translation", fontsize=9)
            axis.set_ylabel("MAPE")
        else:
            for label, (color, style, text) in styles.items():
                values = [e["datasets"][name]["mae"][label].get(variable) for e in entries]
                if label == "reference":  # one model: a level line
                    axis.axhline(values[-1], color=color, linestyle="--", label=text)
                else:
                    axis.plot(xs, values, style, color=color, label=text)
            axis.set_title(f"{name}: {variable}", fontsize=9)
            axis.set_ylabel(f"MAE ({variable.rsplit('_', 1)[-1]})")
        axis.set_xscale("log")
        axis.set_xticks(xs, [f"{x:g}" for x in xs], fontsize=8)
        axis.xaxis.set_minor_locator(NullLocator())
        axis.set_xlabel("real training rows per dataset")
        axis.grid(alpha=0.3)
        top = axis.secondary_xaxis("top", functions=(lambda n: n * ROBOT_S_PER_ROW / 60.0,
                                                     lambda m: m * 60.0 / ROBOT_S_PER_ROW))
        minutes = [x * ROBOT_S_PER_ROW / 60.0 for x in xs]
        top.set_xticks(minutes, [f"{m:.3g}" for m in minutes], fontsize=8)
        top.xaxis.set_minor_locator(NullLocator())
        top.set_xlabel("robot minutes per dataset", fontsize=8)
        axis.legend(fontsize=6)
    for axis in list(axes.flat)[len(panels):]:
        axis.set_visible(False)
    figure.suptitle(f"{record['sensor']} {record['contact']}: profile {record['profile']}", fontsize=10)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=80)
    plt.close(figure)


# ------------------------------------------------------------------------------------------------ command line
def add_arguments(parser: argparse.ArgumentParser) -> None:
    from simshear_gym.models.device import DEVICES

    parser.add_argument("config", type=Path, help="experiment config (TOML), e.g. configs/tactip331.toml")
    add_set_argument(parser)
    parser.add_argument("--real-rows", nargs="+", required=True, metavar="N",
                        help="budgets: real training rows per dataset (integers >= 1), 'all' for every row")
    parser.add_argument("--profile", default="quick", help="stage settings (default quick)")
    parser.add_argument("--scale-epochs", type=float, default=None, metavar="CAP",
                        help="train the models on N rows all/N times the profile's epochs, at most CAP times "
                             "(default: the profile's epochs, so fewer rows train fewer optimiser steps)")
    parser.add_argument("--rows-from", choices=ROWS_FROM, default="random",
                        help="which N rows of each training set: random (one seeded draw, a smaller budget's rows "
                             "among a larger one's: a collection of random poses; default) or first (the set's "
                             "first N: only where its rows are in collection order)")
    parser.add_argument("--out", type=Path, default=None,
                        help="run folder (default runs/pipeline/<sensor>; shares stages with pipeline run there)")
    parser.add_argument("--data", type=Path, default=None,
                        help="data root the config's paths are relative to (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--record", type=Path, default=None, metavar="PREFIX",
                        help="records and figures as PREFIX_<contact>.json / .png (default "
                             "results/ablations/pipeline_sweep_<sensor>_<profile>)")
    parser.add_argument("--workers", type=int, default=2, help="rendering processes of the collect stage")
    parser.add_argument("--jobs", type=int, default=None, help="training steps side by side (default: the profile's)")
    parser.add_argument("--device", choices=DEVICES, default=None, help="where the training steps train")
    parser.add_argument("--contacts", nargs="+", default=None, metavar="CONTACT",
                        help="only these contact types' datasets (default: all)")


def run(args: argparse.Namespace) -> int:
    from simshear_gym.pipelines.run import PLUMBING_PROFILES, config_and_root, contacts_of

    budgets = parse_budgets(args.real_rows)
    config, root = config_and_root(args, args.contacts)
    out = args.out or Path("runs") / "pipeline" / config.name
    prefix = args.record or Path("results") / "ablations" / f"pipeline_sweep_{config.name}_{args.profile}"
    body = run_sweep(config, out, root, args.profile, budgets, scale_cap=args.scale_epochs, workers=args.workers,
                     jobs=args.jobs, device=args.device, rows_from=args.rows_from)
    from simshear_gym.machine import machine_info

    command = recorded_command("simshear pipeline sweep", add_arguments, args)
    for contact, names in contacts_of(config).items():
        json_path = Path(f"{prefix}_{contact}.json")
        record = {
            "command": command, "sensor": config.name, "contact": contact, "datasets": names,
            "profile": args.profile,
            **({"purpose": PLUMBING_PROFILES[args.profile]} if args.profile in PLUMBING_PROFILES else {}),
            "produced_by": "simshear_gym.pipelines.sweep", "git_commit": body["commit"],
            "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "machine": machine_info(), "device": body["device"], "jobs": body["jobs"], "wall_s": body["wall_s"],
            "load_1min": body["load_1min"], "stages": body["stages"],
            "run_folder": recorded_path(out, outside="relpath"),
            "collection_rate_s_per_row": ROBOT_S_PER_ROW,
            "rows_from": ("the first N rows of each training set" if args.rows_from == "first" else
                          f"N rows of each training set drawn at random (seed {SUBSET_SEED}; a smaller budget's "
                          "among a larger one's)"),
            "epochs": ("scaled: the models on N rows train all/N times the profile's epochs, at most "
                       f"{args.scale_epochs}" if args.scale_epochs else "the profile's (fewer rows, fewer steps)"),
            "chain": "a shPix2pix and the profile's pool generators on the N real pairs (a pose-consistency "
                     "generator read by the GDNN on the N real images); a GDNN on their translations of the sim "
                     "renders of every training row (and the profile's random sim contacts); the profile's "
                     "baselines left out",
            "train_rows": {name: body["train_rows"][name] for name in names},
            "val_rows": {name: body["val_rows"][name] for name in names},
            "variables": body["variables"][contact], "budgets": body["budgets"][contact],
            "figure": recorded_path(json_path.with_suffix(".png"), outside="relpath")}
        write_json(json_path, record)
        plot_contact(record, json_path.with_suffix(".png"))
        print(f"{config.name} {contact}: {len(budgets)} budgets; record {json_path}, figure "
              f"{json_path.with_suffix('.png')}")
    return 0


