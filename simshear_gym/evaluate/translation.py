"""Sim-to-real translation measured on the **real** validation images (the paper's Table 1 and more).

For each tactip331 validation set (surface/edge x shear/tap, 2000 rows each) the val rows are rendered with our
simulated TacTip (the same renderer as the paired training sets), their shear vectors computed, and each model
translates them; the generated images are compared with the real images of the same contacts:

- MAPE: mean |generated - real| with both images in [0, 1];
- SSIM: ``skimage.metrics.structural_similarity`` with ``data_range=1``, averaged over images.

Reference rows: ``nearest-label retrieval`` (the real training image whose labels are closest, labels scaled by
their ranges, the edge angle as sin/cos), and each model fed the **published** Tactile Gym sim images of the same
rows instead of ours. ``simshear evaluate translation --model shpix2pix=PATH --model pix2pix=PATH`` writes
``results/translation.json`` and the figure ``results/translation.png`` (sim | each model | real). A ``.pt`` file
runs on torch (so does a zoo folder, ``simshear ship zoo``; ``hf://OWNER/NAME`` is one on the Hugging Face Hub), a
``.onnx`` file (``simshear ship onnx``) on ONNX Runtime, e.g.
``--model shpix2pix:surface=W.pt --model shpix2pix_onnx:surface=W.onnx`` compares the two runtimes.

Pose fidelity (``--reader CONTACT=PATH``, optional): a GDNN trained on the **real** training images of that contact
(``simshear train posenet --source real``) reads every method's images of the val contacts; its per-variable MAE
against the val rows' labels (``reader_mae``, mm / deg) says whether a generated image shows *its* contact the way
a real one would, which pixel MAPE cannot tell apart from marker noise. The reader's MAE on the real val images
themselves is the floor (``reader.real_images``).

``--device`` runs the torch translators and the readers on a GPU (``auto``: CUDA where there is one; ONNX files
stay on ONNX Runtime's CPU provider).
"""

from __future__ import annotations

import argparse
import io
import time
from pathlib import Path

import numpy as np

from simshear_gym.data.labels import CONTACT_TYPES
from simshear_gym.data.paths import data_root, published_sim_set_dir, real_set_dir
from simshear_gym.data.tactile_set import TactileSet, read_set
from simshear_gym.evaluate.figures import pyplot
from simshear_gym.evaluate.model_specs import parse_contact_paths, parse_models
from simshear_gym.evaluate.records import write_record
from simshear_gym.io import atomic_write, recorded_path
from simshear_gym.models.device import DEVICES

# torch (via evaluate.metrics and models) and pybullet (via sim) are imported inside the functions that use them,
# so that `simshear evaluate translation --help` stays light.

KINDS = ("shear", "tap")


def label_features(tactile_set: TactileSet, contact: str) -> np.ndarray:
    """Labels scaled by their ranges for nearest-label retrieval (edge angle as sin, cos)."""
    poses, shear = tactile_set.poses(), tactile_set.shear_sensor()
    if contact == "surface":
        pose_features = [poses[:, 2] / 3.0, poses[:, 3] / 30.0, poses[:, 4] / 30.0]
    else:
        angle = np.deg2rad(poses[:, 5])
        pose_features = [poses[:, 1] / 12.0, poses[:, 2] / 2.0, np.sin(angle) / 2, np.cos(angle) / 2]
    shear_features = [shear[:, j] / 10.0 for j in (0, 1, 3, 4, 5)]
    return np.stack(pose_features + shear_features, axis=1)


def nearest_rows(train_features: np.ndarray, val_features: np.ndarray, chunk: int = 500) -> np.ndarray:
    """(N_val,) index of the training row nearest (Euclidean) to each val row's features."""
    nearest = np.empty(len(val_features), dtype=np.int64)
    for start in range(0, len(val_features), chunk):
        distance = ((val_features[start:start + chunk, None] - train_features[None]) ** 2).sum(-1)
        nearest[start:start + chunk] = distance.argmin(1)
    return nearest


def nearest_label_images(train: TactileSet, val: TactileSet, contact: str) -> np.ndarray:
    """For every val row, the real training image whose labels are closest."""
    return train.load_images()[nearest_rows(label_features(train, contact), label_features(val, contact))]


def reader_mae(reader, images: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Per-variable MAE (mm / deg) of a GDNN reading uint8 (N, H, W) images whose contacts have labels ``truth``."""
    from simshear_gym.evaluate.metrics import metrics
    from simshear_gym.models.gdnn_input import predict

    figures = metrics(*predict(reader, images), truth, reader.variables)
    return {name: per["mae"] for name, per in figures["variables"].items()}


def on_device(translator, device):
    """``translator`` run on ``device`` (a torch.device): a torch translator's generator there behind the same
    call (uint8 in and out); the translator itself on the CPU or for ONNX Runtime."""
    from simshear_gym.models.device import OnDevice
    from simshear_gym.models.translator import Translator

    if device.type == "cpu" or not isinstance(translator, Translator):
        return translator
    return Translator(OnDevice(translator.generator, device), translator.card, fast=False)


def parse_readers(specs: list[str]) -> dict[str, Path]:
    """``--reader CONTACT=PATH`` -> {contact: path}."""
    return parse_contact_paths(specs, "--reader")


def evaluate(root: Path, models: dict[str, dict[str, Path]], rows: int | None = None, workers: int = 2,
             published_input: bool = True, readers: dict[str, Path] | None = None,
             device: str = "cpu") -> tuple[dict, dict, dict]:
    """Figures per set and method, the readers' MAE on the real val images per set (empty without readers),
    and image stacks for the figure; ``device``: where the torch translators and the readers run
    (:data:`~simshear_gym.models.device.DEVICES`)."""
    from simshear_gym.evaluate.metrics import mape, ssim, truth_labels
    from simshear_gym.models.device import OnDevice, resolve_device
    from simshear_gym.models.translator import translate_rows
    from simshear_gym.models.translator_runtime import ONNX_SUFFIX, load_translator
    from simshear_gym.models.zoo import load_posenet, model_path
    from simshear_gym.sim.replay import render_poses
    from simshear_gym.sim.shear import ShearTrackerConfig, replay_shear

    # a .onnx file runs on ONNX Runtime, a .pt file on torch (never swapped for the .onnx beside it)
    where = resolve_device(device)
    models = {name: {contact: model_path(path) for contact, path in per.items()} for name, per in models.items()}
    translators = {(name, contact): on_device(load_translator(path, "onnx" if path.suffix == ONNX_SUFFIX
                                                              else "torch"), where)
                   for name, per in models.items() for contact, path in per.items()}
    reader_models = {contact: load_posenet(path)[0] for contact, path in (readers or {}).items()}
    if where.type != "cpu":
        reader_models = {contact: OnDevice(model, where) for contact, model in reader_models.items()}
    results: dict = {}
    reader_floor: dict = {}
    stacks: dict = {}
    contacts = [c for c in CONTACT_TYPES if all(c in per for per in models.values())]
    if not contacts:
        raise ValueError(f"no contact type has weights for every model: {models}")
    for contact in contacts:
        for kind in KINDS:
            val = read_set(real_set_dir(root, contact, kind, "val"))
            select = slice(0, rows)
            poses, moves = val.poses()[select], val.moves()[select]
            real = val.load_images()[select]
            sim = render_poses(contact, poses, workers=workers)
            shear = replay_shear(poses, moves, ShearTrackerConfig())
            published = read_set(published_sim_set_dir(root, contact, kind, "val")).load_images()[select]
            generated = {"nearest-label retrieval": nearest_label_images(
                read_set(real_set_dir(root, contact, kind, "train")), val, contact)[select]}
            for name in models:
                translator = translators[(name, contact)]
                generated[name] = translate_rows(translator, sim, shear)
                if published_input:
                    generated[f"{name} (published sim input)"] = translate_rows(translator, published, shear)
            set_name = f"{contact}_{kind}"
            results[set_name] = {method: {"mape": float(mape(images, real).mean()),
                                          "ssim": float(ssim(images, real).mean())}
                                 for method, images in generated.items()}
            if contact in reader_models:
                reader = reader_models[contact]
                truth = truth_labels(val, reader.variables)[select]
                reader_floor[set_name] = reader_mae(reader, real, truth)
                for method, images in generated.items():
                    results[set_name][method]["reader_mae"] = reader_mae(reader, images, truth)
            stacks[set_name] = {"sim": sim, **{m: g for m, g in generated.items() if "(" not in m}, "real": real}
    return results, reader_floor, stacks


def figure(stacks: dict, path: Path, per_set: int = 3) -> None:
    """Rows of (sim | models... | real) for a few contacts of each set, like the paper's figure."""
    plt = pyplot()

    rows = [(set_name, i) for set_name in stacks for i in np.linspace(0, len(stacks[set_name]["sim"]) - 1,
                                                                       per_set).astype(int)]
    columns = list(next(iter(stacks.values())).keys())
    fig, axes = plt.subplots(len(rows), len(columns), figsize=(1.6 * len(columns), 1.6 * len(rows)))
    for r, (set_name, i) in enumerate(rows):
        for c, column in enumerate(columns):
            image = stacks[set_name][column][i]
            axes[r, c].imshow(np.clip(image.astype(np.float32) * (4 if column == "sim" else 1), 0, 255),
                              cmap="gray", vmin=0, vmax=255)
            axes[r, c].set_xticks([]), axes[r, c].set_yticks([])
            if r == 0:
                axes[r, c].set_title(column, fontsize=7)
            if c == 0:
                axes[r, c].set_ylabel(set_name.replace("_", " "), fontsize=7)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=110, format="png")
    plt.close(fig)
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(_palette_png(buffer.getvalue())))


def _palette_png(png: bytes) -> bytes:
    """The same picture as a palette PNG where it has at most 256 colours (grey images and black text: lossless,
    about a third of the RGBA file), else unchanged."""
    from PIL import Image

    image = Image.open(io.BytesIO(png)).convert("RGB")
    if image.getcolors(256) is None:
        return png
    out = io.BytesIO()
    image.convert("P", palette=Image.Palette.ADAPTIVE, colors=256).save(out, format="png", optimize=True)
    return out.getvalue()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--model", action="append", default=[], metavar="NAME[:CONTACT]=PATH",
                        help="a translator to evaluate (.pt or a zoo folder: torch, .onnx: ONNX Runtime; "
                             "hf://OWNER/NAME: a Hugging Face Hub id); repeat for several (default: the shipped .pt "
                             "ones)")
    parser.add_argument("--data", type=Path, default=None, help="data root (default $SIMSHEAR_DATA or ../shared/data)")
    parser.add_argument("--rows", type=int, default=None, help="only the first ROWS of each val set (default all)")
    parser.add_argument("--workers", type=int, default=2, help="processes rendering the sim images (default 2)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="results directory (default results)")
    parser.add_argument("--name", default="translation", help="base name of the json and png written")
    parser.add_argument("--reader", action="append", default=[], metavar="CONTACT=PATH",
                        help="a GDNN trained on that contact's real images, to read every method's images "
                             "(pose fidelity); repeat per contact type")
    parser.add_argument("--device", choices=DEVICES, default="auto",
                        help="where the torch translators and the readers run: auto (CUDA where torch finds it, else "
                             "the CPU), cpu or cuda (an error without CUDA) (default: auto)")


def _maes_text(maes: dict[str, float]) -> str:
    return " ".join(f"{name} {value:.3f}" for name, value in maes.items())


def run(args: argparse.Namespace) -> int:
    from simshear_gym.models.zoo import shipped_translators

    specs = args.model or [f"{name}:{contact}={path}" for (name, contact), path in shipped_translators().items()]
    models = parse_models(specs)
    readers = parse_readers(args.reader)
    start = time.perf_counter()
    results, reader_floor, stacks = evaluate(data_root(args.data), models, args.rows, args.workers,
                                             readers=readers, device=args.device)
    png = args.out / f"{args.name}.png"
    figure(stacks, png)
    write_record("simshear evaluate translation", add_arguments, args, args.out / f"{args.name}.json", {
        "rows_per_set": args.rows or "all (2000)",
        "metrics": "MAPE = mean |generated - real| in [0, 1]; SSIM skimage data_range 1; real validation images",
        "models": {name: {c: recorded_path(p) for c, p in per.items()} for name, per in models.items()},
        "sets": results, "figure": str(png), "seconds": round(time.perf_counter() - start, 1),
        **({"reader": {"models": {c: recorded_path(p) for c, p in readers.items()}, "real_images": reader_floor,
                       "metric": "reader_mae: MAE (mm / deg) of a GDNN trained on the real training images "
                                 "reading each method's images, against the val rows' labels"}}
           if readers else {}),
    })
    for set_name, methods in results.items():
        for method, figures in methods.items():
            read = "  reader " + _maes_text(figures["reader_mae"]) if "reader_mae" in figures else ""
            print(f"{set_name:14s} {method:40s} MAPE {figures['mape']:.4f}  SSIM {figures['ssim']:.3f}{read}")
        if set_name in reader_floor:
            print(f"{set_name:14s} {'(reader on the real images)':40s} "
                  + _maes_text(reader_floor[set_name]))
    print(f"wrote {args.out / (args.name + '.json')} and {png}")
    return 0
