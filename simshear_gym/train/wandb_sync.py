"""``--wandb PROJECT`` on the trainers (``simshear train translator|posenet|rl``): the run's tensorboard logs
mirrored to Weights & Biases as they are written (``wandb.init(sync_tensorboard=True)``), with the run's settings
as the W&B run's config. W&B is an optional extra (``pip install -e ".[wandb]"``); without it the flag costs one
line and the run logs to tensorboard as always. A resumed run (``--resume``) continues its W&B run: the run id is
kept in the run folder (``wandb_run_id.txt``). Torch-free."""

from __future__ import annotations

import contextlib
import uuid
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

RUN_ID_FILE = "wandb_run_id.txt"
MISSING = ("--wandb: the wandb package is not installed (pip install -e \".[wandb]\"); logging to tensorboard "
           "only")
FLAG_HELP = ("also log to Weights & Biases, in this project: the run's tensorboard logs mirrored as they are "
             "written (needs the wandb extra; without it, one line and tensorboard only)")


def run_id(run_dir: Path) -> str:
    """The W&B run id of a run folder: made on the first call, read back on a resume."""
    path = Path(run_dir) / RUN_ID_FILE
    if path.is_file():
        return path.read_text().strip()
    path.parent.mkdir(parents=True, exist_ok=True)
    made = uuid.uuid4().hex[:12]
    path.write_text(made + "\n")
    return made


@contextlib.contextmanager
def wandb_run(project: str | None, run_dir: Path, config: Mapping[str, Any]) -> Iterator[Any]:
    """A W&B run mirroring ``run_dir``'s tensorboard logs while the block runs (enter it before the trainer makes its
    tensorboard writer), or nothing: ``project`` None, or wandb not installed (one line says so)."""
    if project is None:
        yield None
        return
    try:
        import wandb
    except ImportError:
        print(MISSING)
        yield None
        return
    run = wandb.init(project=project, dir=str(run_dir), name=Path(run_dir).name, id=run_id(run_dir),
                     resume="allow", config=dict(config), sync_tensorboard=True)
    try:
        yield run
    finally:
        run.finish()


__all__ = ["FLAG_HELP", "MISSING", "RUN_ID_FILE", "run_id", "wandb_run"]
