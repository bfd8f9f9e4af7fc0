"""Ship a policy of ``simshear train rl``: ``simshear train export-policy --run RUN --to DIR --train-command ...``.

A shipped policy is a folder, the layout :meth:`~simshear_gym.control.policy.SB3Controller.load` reads:
``model.zip`` (the run's ``best_model.zip`` by default, ``--model final``: its ``model.zip``), ``vecnormalize.pkl``
(that model's VecNormalize statistics), ``config.json`` (the run's settings, so the benchmark and the robot rebuild
the observation it was trained on, plus the sha256 of the translator and GDNN that made its observations at export)
and the card ``model.md``: the exact command, the budget and the seed, the run's own evaluations and, with
``--results``, the figures of ``simshear evaluate servo`` on it.

``simshear evaluate servo --variants ppo --policy-ppo DIR/model.zip`` and ``simshear rollout --policy
DIR/model.zip`` load it like a run folder.
"""

from __future__ import annotations

import argparse
import datetime
import json
import shutil
from pathlib import Path

from simshear_gym.io import atomic_write, recorded_path, write_json
from simshear_gym.pipelines.ship import WEIGHTS_DIR

POLICY_WEIGHTS_DIR = WEIGHTS_DIR / "policies"
"""Where the package's policies live: ``policies/<name>/model.zip`` with its card ``model.md``."""
MODEL_CHOICES = ("best", "final")
ENV_MODELS = {"tracking": ("SimShearTracking-v0", "surface"), "colift": ("SimShearCoLift-v0", "colift")}
"""task -> (env id, the shipped GDNN its estimate observation reads)."""


def source_files(run: Path, model: str) -> tuple[Path, Path | None]:
    """The model ``.zip`` of a run (``best``: ``best_model.zip``, ``final``: ``model.zip``) and its VecNormalize
    statistics (None for a run without normalisation).

    Raises:
        FileNotFoundError: the run lacks that model or its ``config.json``.
    """
    from simshear_gym.control.policy import RUN_CONFIG, vecnormalize_path

    if model not in MODEL_CHOICES:
        raise ValueError(f"model must be one of {MODEL_CHOICES}, got {model!r}")
    if not (run / RUN_CONFIG).is_file():
        raise FileNotFoundError(f"{run} is not a run of simshear train rl: no {RUN_CONFIG}")
    zip_path = run / ("best_model.zip" if model == "best" else "model.zip")
    if not zip_path.is_file():
        hint = " (the run never evaluated: pass --model final, or train with --eval-steps)" if model == "best" else ""
        raise FileNotFoundError(f"no {zip_path.name} in {run}{hint}")
    config = json.loads((run / RUN_CONFIG).read_text())
    stats = vecnormalize_path(zip_path)
    if config.get("normalize", True) and stats is None:
        raise FileNotFoundError(f"{zip_path} was trained with VecNormalize but its statistics are missing in {run}")
    return zip_path, stats


def model_hashes(task: str) -> dict[str, str]:
    """sha256 of the shipped translator and GDNN that make a task's estimate observation now."""
    from simshear_gym.control.policy import shipped_estimator_file
    from simshear_gym.models.translator_runtime import file_sha256

    names = ("translator_shpix2pix_surface", f"posenet_{ENV_MODELS[task][1]}")
    return {name: file_sha256(shipped_estimator_file(name)) for name in names}


def export(run: Path, to: Path, train_command: str, model: str = "best", results: Path | None = None,
           variant: str = "ppo", date: str | None = None) -> Path:
    """Copy a run's policy into ``to`` and write its card; returns the card's path."""
    run, to = Path(run), Path(to)
    zip_path, stats = source_files(run, model)
    config = json.loads((run / "config.json").read_text())
    to.mkdir(parents=True, exist_ok=True)
    atomic_write(to / "model.zip", lambda tmp: shutil.copyfile(zip_path, tmp), suffix=".zip")
    if stats is not None:
        atomic_write(to / "vecnormalize.pkl", lambda tmp: shutil.copyfile(stats, tmp), suffix=".pkl")
    elif (to / "vecnormalize.pkl").exists():
        (to / "vecnormalize.pkl").unlink()
    provenance = {"train_command": train_command, "exported_from": f"{run.name}/{zip_path.name}",
                  "estimator_models_sha256": model_hashes(config["task"])}
    write_json(to / "config.json", {**config, "provenance": provenance})
    evaluations = _read_json(run / "evaluations.json").get("evaluations", [])
    summary = _read_json(run / "summary.json")
    servo = _read_json(results) if results is not None else {}
    card = card_text(config, provenance, to, model, evaluations, summary, servo, variant, results,
                     date or datetime.date.today().isoformat())
    atomic_write(to / "model.md", lambda tmp: Path(tmp).write_text(card), suffix=".md")
    return to / "model.md"


def _read_json(path: Path) -> dict:
    return json.loads(Path(path).read_text()) if Path(path).is_file() else {}


def card_text(config: dict, provenance: dict, to: Path, model: str, evaluations: list[dict], summary: dict,
              servo: dict, variant: str, results: Path | None, date: str) -> str:
    """The Markdown card of a shipped policy."""
    env_id, posenet = ENV_MODELS[config["task"]]
    size_mib = (to / "model.zip").stat().st_size / 2**20
    # best_model.zip is the model of the last evaluation that set a new best
    chosen = next((entry for entry in reversed(evaluations) if entry.get("best")), None) if model == "best" else (
        evaluations[-1] if evaluations else None)
    arch = config.get("net_arch") or "the algorithm's default"
    observation = {"tactile": "the translated tactile image and the TCP pose (CNN)",
                   "estimate": f"the servo controller's estimate: the shipped `{posenet}` GDNN's mean and std and the "
                               "Bayesian filter's state, normalised (MLP)",
                   "tactile+estimate": "the translated image and the estimate",
                   "estimate+action": f"the servo controller's estimate (the shipped `{posenet}` GDNN's mean and std "
                                      "and the Bayesian filter's state, normalised) and the last action (MLP)",
                   }[config["observation"]]
    lines = [
        f"# {config['algo'].upper()} policy, {config['task']}",
        "",
        f"- Files: `model.zip` ({size_mib:.2f} MiB), `vecnormalize.pkl` (observation statistics), `config.json` "
        "(the env settings it was trained with)",
        f"- Date: {date}",
        f"- Env: `{env_id}`, randomised episodes (random trajectories; scale, speed, turn and start drawn per reset), "
        f"`obs_mode={config['obs_mode']}` ({config['image_size_px']} px images through the shipped shPix2pix), "
        f"{config['n_envs']} sub-envs ({config['vec']}).",
        f"- Observation: {observation}; history {config['history']} frames"
        + ("; residual on the servo law, bound " f"{config['residual_bound']}" if config.get("residual_bound") else
           "; acts alone (not residual)") + ".",
        f"- Agent: {config['algo'].upper()}, hidden layers {arch}, n_steps {config['n_steps']} per sub-env, batch "
        f"{config['batch_size']}, {config['n_epochs']} epochs, gamma {config['gamma']}, learning rate "
        f"{config['learning_rate']}, seed {config['seed']}, {config['threads']} torch thread(s), "
        f"{config['device']}.",
        ("- Budget: no RL steps (the clone's env steps below)." if not config["timesteps"] else
         f"- Budget: {config['timesteps']} env steps"
         + (f", capped at {config['minutes']:g} min" if config.get("minutes") else "")
         + (f"; ran {summary['timesteps']} steps in {summary['seconds'] / 60:.1f} min on a 2-core CPU (stopped by "
            f"{summary['stopped_by']})" if summary else "") + "."),
        *([_imitation_line(summary["imitation"], config)] if summary.get("imitation") else []),
        f"- Exact command: `{provenance['train_command']}`, then `simshear train export-policy --run RUN --to "
        f"{recorded_path(to)} --model {model}" + (f" --results {recorded_path(results)}" if results else "") + "`.",
        "- Made its observations with (sha256 at export): "
        + ", ".join(f"{name} `{digest[:12]}`" for name, digest in provenance["estimator_models_sha256"].items())
        + ". A new translator or GDNN changes what it sees: train it again.",
    ]
    if chosen is not None:
        lines += ["", f"## Training evaluation ({model} model)", "",
                  f"At {chosen['timesteps']} env steps ({chosen['wall_s'] / 60:.1f} min), the deterministic policy on "
                  f"the nominal episodes: mean contact error {chosen['contact_error_mean_mm']:.3f} mm, "
                  f"{chosen['ended_early']} ended early; "
                  + ", ".join(f"{name} {run['contact_error_mean_mm']:.3f} mm ({run['steps']} steps)"
                              for name, run in chosen["episodes"].items()) + "."]
    section = servo.get("results", {}).get(variant, {})
    if section:
        lines += ["", "## Closed loop (`simshear evaluate servo`)", "", f"From `{servo.get('command')}`:", "",
                  "| run | contact error mean +- std over runs (mm) | max (mm) | runs | ended early | contact losses "
                  "| drops |", "|---|---|---|---|---|---|---|"]
        for name, row in section.items():
            lines.append(f"| {name} | {row['contact_error_mean_mm']:.3f} +- {row['contact_error_mean_std_mm']:.3f} | "
                         f"{row['contact_error_max_mm']:.2f} | {row['seeds']} | {row['runs_ended_early']} | "
                         f"{row['runs_with_contact_loss']} | {row['drops']} |")
    return "\n".join(lines) + "\n"


def _imitation_line(imitation: dict, config: dict) -> str:
    """The card's line on the servo law's clone (``--bc-steps``) the policy started from."""
    rounds = imitation.get("rounds", [])
    teacher = ("the servo law in velocity form (the last action plus the change between the newest two frames)"
               if config["observation"] == "estimate+action" else "the servo law on the filter estimate")
    after = imitation.get("after", {}).get("actor_mse")
    return (f"- Start: a DAgger clone of {teacher}: {len(rounds)} round(s) of {config['bc_steps']} steps with "
            f"action noise {imitation.get('noise')}, {imitation.get('epochs')} epochs each"
            + (f", actor MSE against the teacher {after:.2g} after the last round" if after is not None else "")
            + (f", {imitation['seconds'] / 60:.1f} min on a 2-core CPU" if imitation.get("seconds") else "")
            + ("; no RL steps after it (`--timesteps 0`)" if not config["timesteps"] else "") + ".")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", type=Path, required=True, help="run folder of simshear train rl")
    parser.add_argument("--to", type=Path, required=True,
                        help="the shipped policy's folder, e.g. simshear_gym/models/weights/policies/tracking_ppo")
    parser.add_argument("--model", choices=MODEL_CHOICES, default="best",
                        help="best: the run's best evaluated model (best_model.zip), final: its last (model.zip)")
    parser.add_argument("--train-command", required=True, help="the exact simshear train rl command of the run")
    parser.add_argument("--results", type=Path, default=None,
                        help="a results/*.json of simshear evaluate servo on this policy, quoted in the card")
    parser.add_argument("--variant", default="ppo", help="the policy's variant name in --results (ppo, sac, ...)")
    parser.add_argument("--date", default=None, help="the card's date (default today)")


def run(args: argparse.Namespace) -> int:
    card = export(args.run, args.to, args.train_command, args.model, args.results, args.variant, args.date)
    print(f"wrote {args.to / 'model.zip'} and {card}")
    return 0
