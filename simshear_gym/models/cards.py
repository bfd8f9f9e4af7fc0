"""Model cards: a Markdown file beside every shipped weights file (data, exact command, metrics, date)."""

from __future__ import annotations

import json
from pathlib import Path


def write_translator_card(weights: Path, train_command: str, translation_results: Path, contact: str,
                          arch: str, date: str, notes: str = "") -> Path:
    """Write ``<weights>.md`` from the weights' embedded training record and ``results/translation.json``."""
    from simshear_gym.models.weights_io import read_weights

    payload = read_weights(weights, "translator")
    card = payload.get("card", {})
    config = card.get("train_config", {})
    best = card.get("best", {})
    results = json.loads(Path(translation_results).read_text())
    params = sum(v.numel() for v in payload["state_dict"].values())
    run_dir = train_command.split("--out ", 1)[1].split()[0] if "--out " in train_command else "RUN"
    lines = [
        f"# {arch} translator, {contact} contacts",
        "",
        f"- File: `{weights.name}` ({weights.stat().st_size / 2**20:.1f} MiB, fp16, {params / 1e6:.2f} M parameters)",
        f"- Date: {date}",
        f"- Architecture: U-Net generator, {config.get('image_size_px')} px, base {config.get('base_channels')} "
        f"channels (max {config.get('max_channels')}), decoder at {config.get('decoder_scale', 1.0)} x the "
        f"encoder's width, learned at-rest template "
        f"{'on' if config.get('template') else 'off'}"
        + (f", warped by a {config['flow_px']} px displacement field" if config.get("flow_px") else "")
        + ", shear at the bottleneck "
        f"{'on' if arch == 'shpix2pix' else 'off (pix2pix baseline)'}.",
        f"- Data: our sim renders of the real tactip331 `{contact}` training rows (tap and shear, "
        f"`simshear collect --replay-all`), paired with the real images; {config.get('holdout', 0) * 100:.0f}% of "
        "them held out for early stopping. The real validation sets were not used in training or selection.",
        f"- Objective: L1 x {config.get('l1_weight')} + LSGAN x {config.get('gan_weight')}; Adam lr {config.get('lr')} "
        f"({config.get('lr_schedule', 'constant')}), "
        f"batch {config.get('batch_size')}, seed {config.get('seed')}, {config.get('threads')} CPU thread(s).",
        f"- Training: {best.get('epoch')} epochs, best holdout MAPE {best.get('holdout_l1', float('nan')):.4f} at "
        f"{best.get('elapsed_s', 0) / 60:.1f} min on a 2-core CPU (budget {config.get('max_minutes')} min).",
        f"- Exact commands: `simshear collect --replay-all --out runs/paired`, then `{train_command}`, then "
        f"`simshear train export-translator --run {run_dir} "
        f"--contact {contact} --to simshear_gym/models/weights/{weights.name} --train-command '...'`",
        "",
        "## Metrics on the real validation images (2000 per set)",
        "",
        f"From `{results.get('command')}` (`results/translation.json`):",
        "",
        "| set | MAPE | SSIM |",
        "|---|---|---|",
    ]
    for set_name, methods in results["sets"].items():
        if set_name.startswith(contact) and arch in methods:
            lines.append(f"| {set_name} | {methods[arch]['mape']:.4f} | {methods[arch]['ssim']:.3f} |")
    check = card.get("check")
    if check:
        lines += ["", f"Check figure (tests): MAPE {check['mape']:.4f} on the first {check['rows']} rows of the "
                  f"real `{contact}_{check['kind']}` validation set."]
    if notes:
        lines += ["", notes]
    path = weights.with_suffix(".md")
    path.write_text("\n".join(lines) + "\n")
    return path
