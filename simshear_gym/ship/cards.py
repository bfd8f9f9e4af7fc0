"""The Markdown cards of shipped models: what each card says, as text.

A card lies beside what it describes (``W.md`` beside ``W.pt``, ``W.onnx.md`` beside ``W.onnx``, ``model.md`` in a
policy's folder) and says what the file is, when and by which exact commands it was made, from what data, and how
well it does. The ship commands (:mod:`simshear_gym.ship`) gather the records, build their command lines with
:func:`~simshear_gym.command_line.recorded_command` and write the files; the text is made here, one function per
kind of card, from the lines the cards share (file, date, commands, check figure).
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

CHECK_PREFIX = "Check figure (tests):"
CHECK_LINE = re.compile(rf"^{re.escape(CHECK_PREFIX)}.*$", re.MULTILINE)
"""A card's check-figure line (the figure that the tests reproduce); :func:`with_check_line` replaces it."""
CONVERTED = "- Converted to pickle-free files"
"""The start of a policy card's line on its conversion from an older version's pickles."""


# the lines the cards share

def file_line(name: str, size_bytes: int, details: str) -> str:
    """``- File: `name` (1.2 MiB, details)``."""
    return f"- File: `{name}` ({size_bytes / 2**20:.1f} MiB, {details})"


def weights_file_line(weights: Path, precision: str, parameters: int) -> str:
    """The file line of a torch weights file: its size, precision and parameter count."""
    return file_line(weights.name, weights.stat().st_size, f"{precision}, {parameters / 1e6:.2f} M parameters")


def date_line(date: str) -> str:
    return f"- Date: {date}"


def commands_line(commands: Sequence[str], label: str = "Exact commands") -> str:
    """``- Exact commands: `a`, then `b`.``: the commands that made a file, in order."""
    return f"- {label}: " + ", then ".join(f"`{command}`" for command in commands) + "."


def made_by_line(manifest: dict) -> str:
    """The pipeline run (config, profile, commit) that made a file."""
    return (f"- Made by: `{manifest['config']}`, profile `{manifest['profile']}` "
            f"(git {manifest['git_commit'][:10]}).")


def mae_list(mae: dict[str, float]) -> str:
    """``z_mm 0.123, rx_deg 0.456``."""
    return ", ".join(f"{name} {value:.3f}" for name, value in mae.items())


def posenet_check_line(check: dict, contact: str) -> str:
    """A GDNN card's check-figure line: the MAE on the set that the tests measure again."""
    where = (f"a fresh seeded co-lift set ({check['rows']} rows, `EnvCollectConfig(**{check['collect']})`)"
             if check.get("kind") == "env" else
             f"the first {check['rows']} rows of the real `{contact}_shear` validation set")
    return f"{CHECK_PREFIX} MAE on {where}: {mae_list(check['mae'])}"


def recheck_line(check: dict, contact: str, old: dict, command: str) -> str:
    """The check-figure line of a GDNN measured again (:mod:`simshear_gym.ship.recheck_posenet`): when, by which
    command, and for an env GDNN the translator that made its images and the figure it replaces."""
    return (posenet_check_line(check, contact)
            + f" (measured again on {check['measured']} by `{command}`"
            + (f", images from the surface shPix2pix with sha256 {check['translator_sha256'][:16]}...; was "
               + mae_list(old["mae"]) if "translator_sha256" in check else "") + ")")


def with_check_line(text: str, line: str) -> str:
    """A card's text with its check-figure line replaced by ``line`` (appended where it has none)."""
    return (CHECK_LINE.sub(lambda _: line, text, count=1) if CHECK_LINE.search(text)
            else text.rstrip("\n") + "\n\n" + line + "\n")


def generator_list(translators: list[str]) -> str:
    """``a, b (x3), c``: the generator files of ``--translators`` in order, each once with how often it is listed."""
    counts = Counter(translators)
    return ", ".join(f"`{path}`" + (f" (x{counts[path]})" if counts[path] > 1 else "") for path in counts)


# a posenet run's GDNN (simshear ship posenet)

def posenet_card(weights: Path, card: dict, results: dict | None, result_name: str, date: str,
                 export_command: str) -> str:
    """The card of a GDNN shipped from a posenet run: data, exact commands (``export_command``: the ship command,
    its run folder ``RUN``), metrics from a ``simshear evaluate posenet`` results file, check figure."""
    config = card.get("train_config", {})
    params = card.get("parameters")
    holdout = f"{100 * config.get('holdout', 0):.0f} % of them held out for early stopping."
    if config.get("source") == "env":
        data_line = (f"- Data: the env sets {config.get('paired_dirs')} of `simshear collect-env` (the images the env "
                     "emitted, translated by the surface shPix2pix shipped when each set was collected, labelled with "
                     f"the env's true state); {holdout}")
    else:
        translated = (f"translated by each of the generators {generator_list(config['translators'])}, a randomly "
                      "drawn one each time a row is drawn, one listed k times drawn k times as often (the holdout "
                      "by the first)" if config.get("translators")
                      else "translated by the shipped shPix2pix of this contact type")
        data_line = (f"- Data: images from source `{config.get('source')}` of the paired sets "
                     f"{config.get('paired_dirs')} (our sim renders of the real tactip331 training rows; `shpix2pix` = "
                     f"{translated}); {holdout} The real validation images were not used in training or selection.")
    lines = [
        f"# Pose-and-shear GDNN, {card['contact']} contacts",
        "",
        weights_file_line(weights, "fp32", params),
        date_line(date),
        f"- Architecture: GDNN, {config.get('image_size_px')} px input, conv channels {config.get('conv_channels')} "
        f"kernels {config.get('conv_kernels')}, dense {config.get('dense')}; outputs mean and std per variable "
        f"({', '.join(card.get('variables', []))}).",
        data_line,
        f"- Objective: beta-NLL (beta {config.get('beta')}); Adam lr {config.get('lr')} "
        f"({config.get('lr_schedule', 'constant')}), batch "
        f"{config.get('batch_size')}, shift augmentation {config.get('shift')}, seed {config.get('seed')}, "
        f"{config.get('threads')} CPU thread(s).",
        f"- Training: best holdout NLL {card.get('holdout_nll', float('nan')):.3f} at epoch {card.get('epoch')}, "
        f"{card.get('elapsed_s', 0) / 60:.1f} min on a 2-core CPU.",
        _posenet_commands_line(card, export_command),
    ]
    section = (results or {}).get("contacts", {}).get(card["contact"], {})
    if result_name in section.get("models", {}):
        figures = section["models"][result_name]
        lines += ["", "## Metrics on the real validation images", "",
                  f"From `{results.get('command')}` (`results/posenet.json`; {figures['rows']} rows of "
                  f"{section.get('set')}; model `{result_name}`), mean NLL {figures['mean_nll']:.3f}, "
                  f"latency at batch 1 {figures.get('latency_batch1', {}).get('median_ms', float('nan')):.2f} ms "
                  "(median, 1 thread):", "",
                  "| variable | MAE | chance MAE | within 1 std | within 2 std |", "|---|---|---|---|---|"]
        for name, row in figures["variables"].items():
            lines.append(f"| {name} ({row['unit']}) | {row['mae']:.3f} | {row['chance_mae']:.3f} | "
                         f"{row['within_1_std']:.2f} | {row['within_2_std']:.2f} |")
        accepted = section.get("acceptance", {}).get("variables", {})
        if accepted:
            lines += ["", "Against the same GDNN trained on the real training images (`real`, the upper bound): "
                      "MAE ratio per variable that one reads (MAE <= 0.5 x chance): "
                      + ", ".join(f"{name} {row['ratio']:.2f}" for name, row in accepted.items()
                                  if row["reference_reads"])
                      + "; not read by `real` either: " + ", ".join(name for name, row in accepted.items()
                                                               if not row["reference_reads"]) + "."]
    if card.get("check"):
        lines += ["", posenet_check_line(card["check"], card["contact"])]
    return "\n".join(lines) + "\n"


def _posenet_commands_line(card: dict, export_command: str) -> str:
    """The card's exact commands: the sets' collection, the training, the export; one recipe command where
    ``simshear pipeline env-model`` made both sets and run (the data paths are then relative to its run folder)."""
    train = card.get("train_command", "")
    if train.startswith("simshear pipeline env-model"):
        return (f"- Exact commands: `{train}` (the recipe's cached stages: the env sets, a first GDNN, the "
                "servo-driven sets it read, this GDNN; the data paths above are relative to its run folder), then "
                f"`{export_command}` with RUN its `envposenet/final/<hash>/run`.")
    collect = card.get("collect_command", "simshear collect --replay-all --out runs/paired")
    return commands_line([collect, train, export_command])


# a pipeline run's translators and GDNN (simshear ship run)

def _training_line(record: dict, metric: str) -> str:
    metrics = record["metrics"]
    return (f"- Training: {metrics['epochs']} epochs ({metrics['steps']} steps), stopped by {metrics['stopped_by']}; "
            f"best holdout {metric} {metrics[f'best_holdout_{metric}']:.4f}; {record['wall_s'] / 60:.1f} min "
            f"of the run (`{record['folder']}`).")


def pipeline_translator_card(weights: Path, arch: str, contact: str, card: dict, parameters: int, manifest: dict,
                             evaluation: dict, record: dict, datasets: list[str], commands: list[str],
                             date: str) -> str:
    """The card of a translator shipped from a pipeline run: its stage ``record``, the run's ``evaluation`` on the
    real validation rows of ``datasets`` (the config's of this contact type), check figure."""
    config = card["train_config"]
    losses = f"L1 x {config['l1_weight']}"
    if config.get("density_weight"):
        losses += f" + density x {config['density_weight']}"
    if config.get("pose_weight"):
        losses += f" + pose consistency x {config['pose_weight']} on {config.get('pose_variables') or 'all'}"
    if config.get("gan_weight"):
        losses += f" + LSGAN x {config['gan_weight']}"
    lines = [
        f"# {arch} translator, {contact} contacts", "",
        weights_file_line(weights, "fp16", parameters),
        date_line(date),
        made_by_line(manifest),
        f"- Architecture: U-Net generator, {config['image_size_px']} px, base {config['base_channels']} channels "
        f"(max {config['max_channels']}), decoder at {config['decoder_scale']} x the encoder's width, learned at-rest "
        f"template {'on' if config['template'] else 'off'}, shear at the bottleneck "
        f"{'on' if arch == 'shpix2pix' else 'off (pix2pix baseline)'}.",
        f"- Data: the paired sets {config['paired_dirs']} of the run (the config's `{contact}` training rows replayed "
        f"in simulation, beside their real images); {config['holdout'] * 100:.0f} % held out for the best epoch. "
        "The real validation rows were not used in training or selection.",
        f"- Objective: {losses}; Adam lr {config['lr']} ({config['lr_schedule']} over the steps), batch "
        f"{config['batch_size']}, seed {config['seed']}, {config['threads']} CPU thread(s).",
        _training_line(record, "l1"),
        commands_line(commands), "",
        "## Metrics on the real validation rows", "",
        f"From the run's evaluation (`{manifest['evaluation']}`):", "",
        "| set | rows | MAPE | SSIM | nearest-label retrieval MAPE / SSIM |", "|---|---|---|---|---|"]
    for name in datasets:
        entry = evaluation["translation"][name]
        retrieval = entry["nearest-label retrieval"]
        lines.append(f"| {name} | {entry['rows']} | {entry[arch]['mape']:.4f} | {entry[arch]['ssim']:.3f} | "
                     f"{retrieval['mape']:.4f} / {retrieval['ssim']:.3f} |")
    check = card["check"]
    lines += ["", f"{CHECK_PREFIX} MAPE {check['mape']:.4f} on the first {check['rows']} rows of the real "
                  f"`{contact}_{check['kind']}` validation set."]
    return "\n".join(lines) + "\n"


def pipeline_posenet_card(weights: Path, contact: str, card: dict, manifest: dict, evaluation: dict, record: dict,
                          datasets: list[str], commands: list[str], date: str) -> str:
    """The card of a GDNN shipped from a pipeline run: its stage ``record``, the run's evaluation on the real
    validation rows of ``datasets`` against the real-trained reference, check figure."""
    config = card["train_config"]
    lines = [
        f"# Pose-and-shear GDNN, {contact} contacts", "",
        weights_file_line(weights, "fp32", card["parameters"]),
        date_line(date),
        made_by_line(manifest),
        f"- Architecture: GDNN, {config['image_size_px']} px input, conv channels {config['conv_channels']} kernels "
        f"{config['conv_kernels']}, dense {config['dense']}; mean and std per variable "
        f"({', '.join(card['variables'])}).",
        f"- Data: the sim renders of the paired sets {config['paired_dirs']} of the run, each row translated by a "
        f"generator drawn at random from {generator_list(list(config['translators']))} (one listed k times drawn k "
        f"times as often); {config['holdout'] * 100:.0f} % held out for the best epoch. The real images were not "
        "used in training or selection.",
        f"- Objective: beta-NLL (beta {config['beta']}); Adam lr {config['lr']} ({config['lr_schedule']} over the "
        f"steps), batch {config['batch_size']}, shift augmentation {config['shift']}, seed {config['seed']}, "
        f"{config['threads']} CPU thread(s).",
        _training_line(record, "nll"),
        commands_line(commands)]
    for name in datasets:
        readings = evaluation["posenet"][name]
        if "shpix2pix" not in readings:
            continue
        lines += ["", f"## Metrics on the real `{name}` validation rows "
                      f"({evaluation['translation'][name]['rows']})", "",
                  "Against the same GDNN trained on the real training images (`real`, the reference): the ratio "
                  "counts where the reference reads the variable (MAE <= 0.5 x chance).", "",
                  "| variable | MAE | chance MAE | real-trained MAE | ratio |", "|---|---|---|---|---|"]
        for variable, per in readings["shpix2pix"].items():
            if variable == "mean_nll":
                continue
            ratio = readings["ratio_shpix2pix_to_real"][variable]
            read = variable in readings.get("read_by_real", [])
            lines.append(f"| {variable} | {per['mae']:.3f} | {per['chance_mae']:.3f} | "
                         f"{readings['real'][variable]['mae']:.3f} | {ratio:.2f}{'' if read else ' (not read)'} |")
    lines += ["", posenet_check_line(card["check"], contact)]
    return "\n".join(lines) + "\n"


# a translator's ONNX export (simshear ship onnx)

def onnx_card(onnx_path: Path, weights: Path, command: str, precision: str, config, check: dict, evaluation: dict,
              date: str, size_bytes: int, opset: int, gate_relative: float) -> str:
    """The card of an ONNX translator: contract, the check at export (torch against ONNX Runtime), and the
    2000-row evaluation against the ``gate_relative`` gate where ``evaluation`` holds one."""
    arch = "shpix2pix" if config.shear_dim else "pix2pix"
    contact = check["contact"]
    stored = "fp16, computed in fp32 (ONNX Runtime folds the casts at load)" if precision == "fp16" else "fp32"
    lines = [
        f"# {arch} translator, {contact} contacts, ONNX",
        "",
        file_line(onnx_path.name, size_bytes, f"opset {opset}, weights stored {stored}, dynamic batch size") + ".",
        date_line(date),
        f"- Data: the torch generator `{weights.name}` (sha256 `{check['source_sha256'][:16]}...`, recorded in the "
        f"file's metadata; its card `{weights.with_suffix('.md').name}` says how it was trained). Nothing was "
        "trained or tuned for this file.",
        f"- Exact command: `{command}`",
        "- Contract: inputs `sim_uint8` uint8 (B, H, W) and `shear_sensor` float32 (B, 6) sensor-frame shear (mm, "
        "deg) as the shear tracker gives it; output `image_uint8` uint8 (B, H, W). The sim scaling and the shear "
        "mask and scale of `simshear_gym.models.translator` are inside the graph; run it with "
        "`simshear_gym.models.translator_runtime` (the envs' `auto` runtime picks it when onnxruntime is installed).",
        "",
        f"## Check at export: torch and ONNX Runtime on the first {check['rows']} real val rows per set",
        "",
        "| set | MAPE torch | MAPE ONNX | pixels differing | max difference (grey levels) |",
        "|---|---|---|---|---|",
    ]
    for set_name, row in check["sets"].items():
        lines.append(f"| {set_name} | {row['mape_torch']:.5f} | {row['mape_onnx']:.5f} | "
                     f"{100 * row['pixels_differing']:.3f} % | {row['max_abs_difference_grey']} |")
    latency = check["latency"]
    lines += ["", f"Batch-1 latency on one thread (median): torch {latency['torch_ms_batch1']:.2f} ms, ONNX Runtime "
              f"{latency['onnx_ms_batch1']:.2f} ms (load average {latency['load_average_before']} on a shared 2-core "
              "CPU; `simshear evaluate env-speed` measures both in the env step)."]
    lines += ["", "## Metrics on the real validation images (2000 per set)", ""]
    if evaluation:
        lines += [f"From `{evaluation['command']}` (`{evaluation['file']}`); gate: ONNX MAPE at most "
                  f"{100 * gate_relative:.0f} % above torch's on every set.", "",
                  "| set | MAPE torch | MAPE ONNX | relative | SSIM torch | SSIM ONNX | gate |",
                  "|---|---|---|---|---|---|---|"]
        for set_name, row in evaluation["sets"].items():
            passed = "met" if row["relative"] <= gate_relative else "FAILED"
            lines.append(f"| {set_name} | {row['torch']:.5f} | {row['onnx']:.5f} | {100 * row['relative']:+.3f} % | "
                         f"{row['ssim_torch']:.4f} | {row['ssim_onnx']:.4f} | {passed} |")
    else:
        lines.append(f"Not evaluated yet: run `simshear evaluate translation --model {arch}:{contact}={weights} "
                     f"--model {arch}_onnx:{contact}={onnx_path} --name translation_onnx`, then this command again.")
    return "\n".join(lines) + "\n"


# an RL run's policy (simshear ship policy)

def policy_files_line(to: Path) -> str:
    """The card's line on a shipped policy's files."""
    size_mib = (to / "model.pt").stat().st_size / 2**20
    stats = ", `vecnormalize.json` (observation statistics)" if (to / "vecnormalize.json").is_file() else ""
    return (f"- Files: `model.pt` ({size_mib:.2f} MiB, the policy network's state dict), `model.json` (what rebuilds "
            f"the network, with the sha256 of `model.pt`){stats}, `config.json` (the env settings it was trained "
            "with); no pickle: loading runs no code from them")


def converted_card(card: str, folder: Path, command: str) -> str:
    """An older policy's card after its conversion to pickle-free files (``command``): its file line and the line
    on the conversion replaced."""
    lines = [line for line in card.splitlines() if not line.startswith(CONVERTED)]
    at = next((i for i, line in enumerate(lines) if line.startswith("- Files:")), 1)
    lines[at:at + 1] = [policy_files_line(folder), f"{CONVERTED} from the pickled SB3 `model.zip` and "
                        f"`vecnormalize.pkl` it was trained as (`{command}`): the same network and statistics, so "
                        "the same actions."]
    return "\n".join(lines) + "\n"


def policy_card(config: dict, provenance: dict, to: Path, model: str, evaluations: list[dict], summary: dict,
                servo: dict, variant: str, export_command: str, date: str, env: tuple[str, str]) -> str:
    """The Markdown card of a shipped policy; ``env``: (env id, the shipped GDNN its estimate observation reads)."""
    # here, not at the top: the RL config brings gymnasium, which the other cards' commands do not need
    from simshear_gym.train.rl_config import ended_early

    env_id, posenet = env
    # best_model.zip is the model of the last evaluation that set a new best
    chosen = next((entry for entry in reversed(evaluations) if entry.get("best")), None) if model == "best" else (
        evaluations[-1] if evaluations else None)
    arch = config.get("net_arch") or "the algorithm's default"
    task = config["task"]
    controller = {"edge": "edge controller", "push": "push controller"}.get(task, "servo controller")
    observation = {"tactile": "the translated tactile image and the TCP pose (CNN)",
                   "estimate": f"the {controller}'s estimate: the shipped `{posenet}` GDNN's mean and std and the "
                               "Bayesian filter's state, normalised (MLP)",
                   "tactile+estimate": "the translated image and the estimate",
                   "estimate+action": f"the {controller}'s estimate (the shipped `{posenet}` GDNN's mean and std "
                                      "and the Bayesian filter's state, normalised) and the last action (MLP)",
                   }[config["observation"]]
    if task == "push":
        observation += ", and the goal (the target and the path's direction in the sensor frame)"
    error = {"edge": "offset from the edge", "push": "path deviation"}.get(task, "contact error")
    lines = [
        f"# {config['algo'].upper()} policy, {config['task']}",
        "",
        policy_files_line(to),
        date_line(date),
        f"- Env: `{env_id}`, randomised episodes ("
        + {"edge": "random outlines; size, start point, offset and turn",
           "push": "random shapes, paths, masses and frictions"}.get(
            config["task"], "random trajectories; scale, speed, turn and start") + " drawn per reset), "
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
        commands_line([provenance["train_command"], export_command], "Exact command"),
        "- Made its observations with (sha256 at export): "
        + ", ".join(f"{name} `{digest[:12]}`" for name, digest in provenance["estimator_models_sha256"].items())
        + ". A new translator or GDNN changes what it sees: train it again.",
    ]
    if chosen is not None:
        lines += ["", f"## Training evaluation ({model} model)", "",
                  f"At {chosen['timesteps']} env steps ({chosen['wall_s'] / 60:.1f} min), the deterministic policy on "
                  f"the nominal episodes: mean {error} {chosen['contact_error_mean_mm']:.3f} mm, "
                  f"{ended_early(chosen['episodes'])} ended early; "
                  + ", ".join(f"{name} {run['contact_error_mean_mm']:.3f} mm ({run['steps']} steps)"
                              for name, run in chosen["episodes"].items()) + "."]
    section = servo.get("results", {}).get(variant, {})
    if section and servo.get("env") == "SimShearEdgeFollow-v0":
        lines += ["", "## Closed loop (`simshear evaluate edge-follow`)", "", f"From `{servo.get('command')}`:", "",
                  "| outline | laps | offset mean (mm) | worst run (mm) | max (mm) | depth error mean (mm) |",
                  "|---|---|---|---|---|---|"]
        for name, row in section.items():
            lines.append(f"| {name} | {row['laps_completed']}/{row['runs']} | {row['offset_mean_mm']:.3f} | "
                         f"{row['offset_mean_worst_run_mm']:.3f} | {row['offset_max_mm']:.2f} | "
                         f"{row['depth_error_mean_mm']:.3f} |")
    elif section and servo.get("env") == "SimShearPush-v0":
        lines += ["", "## Closed loop (`simshear evaluate push`)", "", f"From `{servo.get('command')}`:", "",
                  "| episodes | within 10 mm | median distance (mm) | path deviation mean (mm) | ends |",
                  "|---|---|---|---|---|",
                  f"| {section['episodes']} | {section['within_10mm']:.0%} | "
                  f"{section['target_distance_median_mm']:.1f} | {section['path_deviation_mean_mm']:.2f} | "
                  + ", ".join(f"{name} {count}" for name, count in section["terminations"].items()) + " |"]
    elif section:
        lines += ["", "## Closed loop (`simshear evaluate servo`)", "", f"From `{servo.get('command')}`:", "",
                  "| run | contact error mean +- std over runs (mm) | max (mm) | runs | ended early | contact losses "
                  "| drops |", "|---|---|---|---|---|---|---|"]
        for name, row in section.items():
            lines.append(f"| {name} | {row['contact_error_mean_mm']:.3f} +- {row['contact_error_mean_std_mm']:.3f} | "
                         f"{row['contact_error_max_mm']:.2f} | {row['seeds']} | {row['runs_ended_early']} | "
                         f"{row['runs_with_contact_loss']} | {row['drops']} |")
    return "\n".join(lines) + "\n"


def _imitation_line(imitation: dict, config: dict) -> str:
    """The card's line on the law's clone (``--bc-steps``) the policy started from (the task's teacher:
    :func:`~simshear_gym.train.rl_imitation.teacher_for`)."""
    rounds = imitation.get("rounds", [])
    teacher = {"edge": "the edge law (proportional only) on the filter estimate",
               "push": "the push law without its path-side integral on the filter estimate and the goal"}.get(
        config["task"], "the servo law in velocity form (the last action plus the change between the newest two "
                        "frames)" if config["observation"] == "estimate+action" else "the servo law on the filter "
                                                                                     "estimate")
    after = imitation.get("after", {}).get("actor_mse")
    return (f"- Start: a DAgger clone of {teacher}: {len(rounds)} round(s) of {config['bc_steps']} steps with "
            f"action noise {imitation.get('noise')}, {imitation.get('epochs')} epochs each"
            + (f", actor MSE against the teacher {after:.2g} after the last round" if after is not None else "")
            + (f", {imitation['seconds'] / 60:.1f} min on a 2-core CPU" if imitation.get("seconds") else "")
            + ("; no RL steps after it (`--timesteps 0`)" if not config["timesteps"] else "") + ".")
