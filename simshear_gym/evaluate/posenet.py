"""Pose-and-shear GDNNs measured on the **real** validation images of a contact type's shear set.

``simshear evaluate posenet --model NAME[:CONTACT]=PATH [--model ...] --contact surface|edge`` runs each GDNN
(``best.pt`` of ``simshear train posenet``) on ``tactip331/real/<task>/shear/csv_val``, or with ``--set DIR`` on any
real tactile set (another sensor's validation split as its pipeline's ``adapt`` stage wrote it:
``runs/pipeline/<sensor>/adapt/<dataset>/<hash>/val``; its ``meta.json`` names the contact type), and reports per
variable:

- ``mae``: mean |predicted mean - truth| in mm / deg (a periodic angle's error wrapped to [-180, 180));
- ``chance_mae``: the same for always predicting the range centre (for a periodic angle: predicting 0);
- ``within_1_std`` / ``within_2_std``: share of rows whose error is at most 1 / 2 predicted std;
- ``mae_by_depth``: the MAEs within each third of the rows by true depth z (shallow, middle, deep);

and ``mean_nll``: the Gaussian NLL per row over the encoded components (nats), as in training. Writes
``results/posenet.json`` (with the command) and ``results/posenet.png`` (predicted against true per variable).
``--device`` runs the GDNNs on a GPU (``auto``: CUDA where there is one); the batch-1 latency is always measured on
the CPU, where the estimator runs.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from simshear_gym.data.labels import CONTACT_TYPES
from simshear_gym.data.paths import data_root, real_set_dir
from simshear_gym.data.tactile_set import read_set
from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.model_specs import parse_models
from simshear_gym.evaluate.records import write_record
from simshear_gym.models.device import DEVICES

# torch (via evaluate.metrics and models) is imported inside the functions that use it, so that
# `simshear evaluate posenet --help` stays light.


def latency_ms(model, repeats: int = 200) -> dict:
    """Median and p95 ms of one image at batch 1 through the frozen inference copy (as the estimator runs it),
    with the torch threads as set."""
    import torch

    inference = model.frozen()
    size = model.config.image_size_px
    image = torch.rand(1, 1, size, size)
    times = []
    with torch.inference_mode():
        for index in range(repeats + 20):
            start = time.perf_counter()
            inference(image)
            if index >= 20:
                times.append(1000 * (time.perf_counter() - start))
    return {"median_ms": float(np.median(times)), "p95_ms": float(np.percentile(times, 95)),
            "torch_threads": torch.get_num_threads()}


def evaluate(root: Path, models: dict[str, Path], contact: str, rows: int | None = None,
             val_dir: Path | None = None, device: str = "cpu") -> tuple[dict, dict]:
    """Figures per model; also (truth, predicted means, stds) per model for the figure. ``val_dir``: the real set
    to read (default: tactip331's ``<contact>`` shear validation set under ``root``); ``device``: where the GDNNs
    read the images (:data:`~simshear_gym.models.device.DEVICES`)."""
    from simshear_gym.evaluate.metrics import metrics, truth_labels
    from simshear_gym.models.device import OnDevice, resolve_device
    from simshear_gym.models.gdnn import VARIABLE_SETS
    from simshear_gym.models.gdnn_input import predict
    from simshear_gym.models.zoo import load_posenet

    where = resolve_device(device)
    val = read_set(val_dir or real_set_dir(root, contact, "shear", "val"))
    select = slice(0, rows)
    images = val.load_images()[select]
    results, arrays = {}, {}
    for name, path in models.items():
        model, card = load_posenet(path)
        variables = model.variables
        if variables.name in VARIABLE_SETS and variables.name != contact:  # an inline set is a sensor's own
            raise ValueError(f"--model {name}={path}: predicts the {variables.name!r} variables, not {contact!r}")
        truth = truth_labels(val, variables)[select]
        latency = latency_ms(model)  # on the CPU, before the model moves
        mean_encoded, std_encoded = predict(model if where.type == "cpu" else OnDevice(model, where), images)
        results[name] = {"path": str(path), "card": card, **metrics(mean_encoded, std_encoded, truth, variables),
                         "latency_batch1": latency}
        mean, std = (t.numpy() for t in variables.decode(mean_encoded, std_encoded))
        arrays[name] = (variables, truth, mean, std)
    return results, arrays


def figure(arrays: dict, path: Path) -> None:
    """One row per model, one panel per variable: predicted mean against truth."""
    plt = pyplot()

    names = list(arrays)
    n_variables = max(variables.dim for variables, *_ in arrays.values())
    fig, axes = plt.subplots(len(names), n_variables, figsize=(2.2 * n_variables, 2.2 * len(names)), squeeze=False)
    for r, name in enumerate(names):
        variables, truth, mean, _ = arrays[name]
        for c, spec in enumerate(variables.variables):
            axis = axes[r, c]
            axis.scatter(truth[:, c], mean[:, c], s=2, alpha=0.4)
            axis.plot([spec.low, spec.high], [spec.low, spec.high], "k--", lw=0.6)
            axis.set_title(f"{name}: {spec.name}" if c == 0 else spec.name, fontsize=7)
            axis.tick_params(labelsize=6)
            if r == len(names) - 1:
                axis.set_xlabel("true", fontsize=7)
            if c == 0:
                axis.set_ylabel("predicted", fontsize=7)
    save_figure(fig, path)


READ_SHARE = 0.5
"""A variable counts as read where its MAE is at most this share of the chance MAE."""


def acceptance(models: dict, reference: str = "real", candidate: str = "shpix2pix", limit: float = 1.2) -> dict:
    """Per variable: whether ``reference`` reads it (MAE <= READ_SHARE x chance) and ``candidate``'s MAE ratio."""
    if reference not in models or candidate not in models:
        return {}
    rows = {}
    for name, ref in models[reference]["variables"].items():
        cand = models[candidate]["variables"][name]
        reads = ref["mae"] <= READ_SHARE * ref["chance_mae"]
        ratio = cand["mae"] / ref["mae"]
        rows[name] = {"reference_reads": bool(reads), "ratio": ratio, "within_limit": bool(ratio <= limit),
                      "candidate_reads": bool(cand["mae"] <= READ_SHARE * cand["chance_mae"])}
    met = all(row["within_limit"] for row in rows.values() if row["reference_reads"])
    return {"reference": reference, "candidate": candidate, "limit": limit, "met": met, "variables": rows}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", action="append", required=True, metavar="NAME[:CONTACT]=PATH",
                        help="a posenet best.pt (or a zoo folder, or hf://OWNER/NAME: a Hugging Face Hub id) to "
                             "evaluate; repeat for several; '{contact}' in PATH is replaced "
                             "by each --contact; NAME:CONTACT=PATH names the model of one contact type")
    parser.add_argument("--contact", choices=CONTACT_TYPES, nargs="+", default=None,
                        help="contact type(s) whose real tactip331 shear val set the models read; one section and "
                             "figure each")
    parser.add_argument("--set", type=Path, default=None, dest="val_set",
                        help="instead of --contact: a real tactile set to read (e.g. a pipeline run's "
                             "adapt/<dataset>/<hash>/val); its meta.json names the contact type")
    parser.add_argument("--data", type=Path, default=None, help="data root (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--rows", type=int, default=None, help="only the first ROWS of the val set (default all)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="results directory (default results)")
    parser.add_argument("--name", default="posenet", help="base name of the json and png written")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (latency is measured with them)")
    parser.add_argument("--device", choices=DEVICES, default="auto",
                        help="where the GDNNs read the images: auto (CUDA where torch finds it, else the CPU), cpu or "
                             "cuda (an error without CUDA); latency is measured on the CPU (default: auto)")


def run(args: argparse.Namespace) -> int:
    val_set = args.val_set
    if (val_set is None) == (args.contact is None):  # before torch: an option error comes at once
        raise ValueError("give --contact (tactip331's real shear val sets) or --set DIR (any real tactile set), "
                         "one of the two")
    import torch

    torch.set_num_threads(args.threads)
    if val_set is not None:
        meta = read_set(val_set).meta
        if meta.get("contact") not in CONTACT_TYPES:
            raise ValueError(f"{val_set}/meta.json: contact {meta.get('contact')!r}; expected one of "
                             f"{list(CONTACT_TYPES)} (a set written by a pipeline's adapt stage names it)")
        contacts = [meta["contact"]]
    else:
        contacts = [args.contact] if isinstance(args.contact, str) else list(args.contact)
    start = time.perf_counter()
    sections = {}
    for contact in contacts:
        models = {name: Path(str(paths[contact]).replace("{contact}", contact))
                  for name, paths in parse_models(args.model).items() if contact in paths}
        results, arrays = evaluate(data_root(args.data), models, contact, args.rows, val_set, args.device)
        png = args.out / f"{args.name}_{contact}.png"
        figure(arrays, png)
        set_name = str(val_set) if val_set is not None else f"real {contact}_shear csv_val"
        sections[contact] = {"set": set_name, "models": results, "figure": str(png),
                             "acceptance": acceptance(results)}
        for name, result in results.items():
            print(f"{contact} {name}: mean NLL {result['mean_nll']:.3f} over {result['rows']} rows")
            for variable, figures in result["variables"].items():
                print(f"  {variable:16s} MAE {figures['mae']:7.3f} (chance {figures['chance_mae']:7.3f})  "
                      f"within 1/2 std {figures['within_1_std']:.2f}/{figures['within_2_std']:.2f}")
        if sections[contact]["acceptance"]:
            print(f"  shpix2pix MAE <= 1.2 x real MAE on every variable real reads: "
                  f"{sections[contact]['acceptance']['met']}")
    write_record("simshear evaluate posenet", add_arguments, args, args.out / f"{args.name}.json", {
        "metrics": "MAE in mm/deg (angles wrapped); chance = always the range centre (0 for a periodic angle); "
                   "within_k_std = share of |error| <= k predicted std; mean_nll = Gaussian NLL per row (nats); "
                   f"a variable is read where MAE <= {READ_SHARE} x chance",
        "contacts": sections, "seconds": round(time.perf_counter() - start, 1),
    })
    print(f"wrote {args.out / (args.name + '.json')}")
    return 0
