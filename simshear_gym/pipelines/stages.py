"""How a pipeline's stages run: cached under content hashes, as a graph of steps ``jobs`` at a time, and stopped
cleanly by a signal.

Cached stages: each stage's work lands in a folder named by a content hash of its inputs and settings, and counts
as done only once its record (``stage.json``) is written, last and atomically. So a rerun of a finished pipeline
finds every record and does nothing; a run killed mid-stage finds that stage's folder without a record and runs the
stage again in the same folder, where a resumable step (a trainer's checkpoint) picks up where it stopped; a change
of settings or of an input's hash gives a new folder. A training stopped by its wall-clock safety cap
(``stopped_by`` :data:`~simshear_gym.train.runs.CAP_STOP`) is not the recipe's model: its stage gets no record and
:class:`StageStopped` says so; the rerun continues it from its last epoch.

The step graph (:func:`run_steps`): a step starts once the steps it needs are done, up to ``jobs`` at a time, each
in a fresh worker process (``jobs`` = 1: one after another in this process). A step is a :class:`Step`: its name,
the steps it needs and its action, ``action(runner, done) -> StageResult``, where ``runner`` is a
:class:`StageRunner` over the run folder and ``done`` holds the records of the steps it needs. Actions must pickle
(module-level functions, or :func:`functools.partial` of them), since a worker process runs them. Among the steps
that are ready, the one with the longest chain of ``cost`` after it starts first, so the critical path (real-image
GDNN -> pose-consistency generators -> GDNN on translated images) is never left waiting behind side branches.

A stopped run stops all of its processes: SIGTERM (a scheduler, ``kill``) and SIGINT (Ctrl-C) become
:class:`RunStopped` in the main process (:func:`stop_on_signals`), so the code that owns the worker processes ends
them on the way out (the step graph's pool; the collect stage's rendering pool), and :func:`end_children` ends
whatever child is left. Python's default for SIGTERM is to die at once, skipping every ``finally``: the workers of a
``multiprocessing`` pool then live on as orphans, still training and writing into the run folder. Nothing a stopped
run leaves breaks a rerun: a stage counts as done only once its record is written, and every file is written
atomically, so the rerun resumes the stopped stages from their checkpoints.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, is_dataclass
from functools import cache
from pathlib import Path
from typing import Any

from simshear_gym.io import write_json
from simshear_gym.train.runs import CAP_STOP

RECORD = "stage.json"


class StageFolderError(ValueError):
    """A stage name that would put its folder (and so its writes) outside the run folder."""


def stage_folder(root: Path, name: str, stage_hash: str) -> Path:
    """``root/<name>/<hash>``, checked to lie inside ``root`` (a name with ``..`` or an absolute part would not),
    before anything is written."""
    parts = Path(name).parts
    if not parts or Path(name).is_absolute() or any(part in ("..", ".", "") for part in parts):
        raise StageFolderError(f"stage name {name!r} would write outside the run folder {root}; expected names "
                               "of letters, digits, '_', '-' separated by '/'")
    folder = root / name / stage_hash
    if not folder.resolve().is_relative_to(root.resolve()):
        raise StageFolderError(f"stage {name!r}: its folder {folder} resolves outside the run folder {root}")
    return folder


def digest(value: Any) -> str:
    """A short, stable content hash of JSON-able settings (dataclasses, paths and tuples allowed)."""
    text = json.dumps(_plain(value), sort_keys=True, separators=(",", ":"))
    return hashlib.sha1(text.encode()).hexdigest()[:12]


def _plain(value: Any) -> Any:
    if is_dataclass(value) and not isinstance(value, type):
        return _plain(asdict(value))
    if isinstance(value, dict) or hasattr(value, "items"):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def file_fingerprint(paths: list[Path]) -> str:
    """A hash of files' names and contents (label files, a few MB: a data set's images are not read). Not of
    their modification times: a copied or re-provisioned data set keeps its cache."""
    digest = hashlib.sha1()
    for path in sorted(paths):
        digest.update(f"{path.name}\n".encode())
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
        digest.update(b"\n")
    return digest.hexdigest()[:12]


def training_start_line(name: str, epochs: int, tensorboard: Path) -> str:
    """The line a training stage logs as it starts: its epochs and where its tensorboard logs go."""
    return f"[{name}] training {epochs} epoch{'s' if epochs != 1 else ''}; tensorboard --logdir {tensorboard}"


def epoch_line(name: str, record: dict, epochs: int, metric: str) -> str:
    """One line of a training stage's progress after an epoch (its ``history`` record: epoch, elapsed_s, holdout):
    the epoch of ``epochs``, the training time so far, the holdout metric and the time left at the epochs' mean
    pace (at most: a patience stop ends sooner)."""
    done, elapsed_s = record["epoch"], record["elapsed_s"]
    left_s = elapsed_s / max(done, 1) * max(epochs - done, 0)
    holdout = record.get(f"holdout_{metric}")
    shown = f", holdout {metric} {holdout:.4g}" if isinstance(holdout, int | float) else ""
    return (f"[{name}] epoch {done}/{epochs}{' (partial)' if record.get('partial_epoch') else ''}: "
            f"{_duration(elapsed_s)}{shown}; ETA {_duration(left_s)}")


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 60 else f"{seconds / 60:.1f} min"


def report_epochs(trainer, name: str, log: Callable[[str], None]) -> None:
    """Make a trainer of :mod:`simshear_gym.train.loop` log :func:`epoch_line` after each of its epochs (beside
    what its ``log_epoch`` writes to tensorboard); the pipeline's workers train with their bars off."""
    tensorboard = trainer.log_epoch

    def log_epoch(writer) -> None:
        tensorboard(writer)
        log(epoch_line(name, trainer.history[-1], trainer.config.epochs, trainer.metric))

    trainer.log_epoch = log_epoch


class StageStopped(RuntimeError):
    """A stage's training stopped by its wall-clock safety cap: no record, so a rerun continues it."""


@dataclass
class StageResult:
    """What a stage left: its folder, its record (outputs, metrics, wall time) and whether it ran now."""

    name: str
    folder: Path
    record: dict
    ran: bool

    @property
    def outputs(self) -> dict:
        return self.record["outputs"]


@dataclass
class StageRunner:
    """Runs stages under ``root`` (``root/<stage>/<hash>/``) and keeps their records for the run's manifest."""

    root: Path
    log: Callable[[str], None] = print
    results: list[StageResult] = field(default_factory=list)

    def run(self, name: str, key: dict, work: Callable[[Path], dict]) -> StageResult:
        """Run ``work(folder) -> {"outputs": {...}, "metrics": {...}}`` unless its record exists.

        ``key`` is everything the stage's result depends on: settings, seeds and its inputs' hashes.
        Output paths in the record are relative to ``root`` and must lie inside it.

        Raises:
            StageFolderError: the stage's folder or an output would lie outside ``root`` (checked before ``work``
                runs for the folder).
        """
        stage_hash = digest(key)
        folder = stage_folder(self.root, name, stage_hash)
        record_path = folder / RECORD
        if record_path.exists():
            record = json.loads(record_path.read_text())
            self.log(f"[{name}] cached ({folder.relative_to(self.root)})")
            result = StageResult(name, folder, record, ran=False)
        else:
            folder.mkdir(parents=True, exist_ok=True)
            resumed = any(folder.iterdir())
            self.log(f"[{name}] {'resuming' if resumed else 'running'} in {folder.relative_to(self.root)}")
            start = time.perf_counter()
            produced = work(folder)
            metrics = produced.get("metrics", {})
            if metrics.get("stopped_by") == CAP_STOP:
                raise StageStopped(
                    f"[{name}] stopped by its wall-clock safety cap (cap_minutes) after {metrics.get('epochs')} "
                    f"finished epochs ({metrics.get('elapsed_s')} s of training) in {folder}: not the recipe's model, "
                    "so it is not recorded. Rerun the same command to continue it from that epoch: each run trains "
                    "a stage for at most cap_minutes (a changed cap_minutes starts the stage afresh)")
            outputs = _plain(produced.get("outputs", {}))
            for output in _leaves(outputs):
                if isinstance(output, str) and (Path(output).is_absolute() or ".." in Path(output).parts):
                    raise StageFolderError(f"[{name}] output {output!r} lies outside the run folder {self.root}")
            record = {"stage": name, "hash": stage_hash, "key": _plain(key),
                      "outputs": outputs, "metrics": _plain(metrics),
                      "wall_s": round(time.perf_counter() - start, 2), "resumed": resumed}
            write_json(record_path, record)
            self.log(f"[{name}] done in {record['wall_s']:.1f} s")
            result = StageResult(name, folder, record, ran=True)
        self.results.append(result)
        return result

    def relative(self, path: Path) -> str:
        """``path`` relative to the run folder (a StageFolderError outside it)."""
        try:
            return str(Path(path).resolve().relative_to(self.root.resolve()))
        except ValueError:
            raise StageFolderError(f"{path} lies outside the run folder {self.root}") from None


def _leaves(value: Any) -> list:
    if isinstance(value, dict):
        return [leaf for item in value.values() for leaf in _leaves(item)]
    if isinstance(value, list):
        return [leaf for item in value for leaf in _leaves(item)]
    return [value]


# --------------------------------------------------------------------------------------------- the step graph
@dataclass(frozen=True)
class Step:
    """One training step of the graph (see the module docstring); ``cost`` is a rough relative duration;
    ``work`` says what it trains, for estimates made before the run (:mod:`simshear_gym.pipelines.estimate`):
    ``trainer`` ("translator" or "posenet"), ``contact``, ``settings`` (its trainer config's fields),
    ``datasets`` (whose training rows it trains on), ``random_rows`` (random sim contacts it adds) and
    ``translators`` (the translator steps whose generators translate its rows, for a GDNN on translations)."""

    name: str
    action: Callable[[StageRunner, dict[str, StageResult]], StageResult]
    needs: tuple[str, ...] = ()
    cost: float = 1.0
    work: Mapping[str, Any] | None = None


def order_steps(steps: list[Step]) -> list[str]:
    """The steps' names by priority: longest chain of cost to the end first (ties: as listed)."""
    by_name = {step.name: step for step in steps}
    if len(by_name) != len(steps):
        raise ValueError(f"step names must differ: {[step.name for step in steps]}")
    for step in steps:
        missing = [need for need in step.needs if need not in by_name]
        if missing:
            raise ValueError(f"step {step.name!r} needs {missing}, which are not steps of the run")
    users: dict[str, list[str]] = {name: [] for name in by_name}
    for step in steps:
        for need in step.needs:
            users[need].append(step.name)

    @cache
    def chain(name: str, seen: frozenset = frozenset()) -> float:
        if name in seen:
            raise ValueError(f"steps needing each other in a cycle through {name!r}")
        return by_name[name].cost + max((chain(user, seen | {name}) for user in users[name]), default=0.0)

    listed = {step.name: i for i, step in enumerate(steps)}
    return sorted(by_name, key=lambda name: (-chain(name), listed[name]))


def run_steps(steps: list[Step], root: Path, jobs: int = 1,
              log: Callable[[str], None] = print) -> dict[str, StageResult]:
    """Run every step (see the module docstring); returns their results by name. A step that fails or stops at its
    wall-clock cap stops the run (the other running steps are ended; their folders stay, so a rerun resumes them).
    A worker's cap stop (:class:`StageStopped`) or bad-input error (ValueError,
    OSError) is raised as it is, as in one process; anything else as a RuntimeError naming the step."""
    priority = order_steps(steps)
    by_name = {step.name: step for step in steps}
    done: dict[str, StageResult] = {}
    if jobs == 1:
        pending = list(priority)
        while pending:
            name = next(name for name in pending if all(need in done for need in by_name[name].needs))
            pending.remove(name)
            step = by_name[name]
            done[name] = step.action(StageRunner(root, log=log), {need: done[need] for need in step.needs})
        return done
    context = multiprocessing.get_context("spawn")
    finished: queue.Queue = queue.Queue()
    running: set[str] = set()
    with context.Pool(jobs, maxtasksperchild=1) as pool:
        try:
            while len(done) < len(steps):
                for name in priority:
                    step = by_name[name]
                    if (len(running) < jobs and name not in done and name not in running
                            and all(need in done for need in step.needs)):
                        running.add(name)
                        pool.apply_async(_run_step, (step.action, root, {need: done[need] for need in step.needs}),
                                         callback=lambda result, name=name: finished.put((name, result, None)),
                                         error_callback=lambda error, name=name: finished.put((name, None, error)))
                name, result, error = finished.get()
                running.discard(name)
                if isinstance(error, StageStopped | ValueError | OSError):
                    raise error  # a cap stop or bad input: its message names the step, file or key (one CLI line)
                if error is not None:
                    raise RuntimeError(f"pipeline step {name!r} failed: {error}") from error
                done[name] = result
                log(f"[{name}] finished ({len(done)}/{len(steps)} steps)")
        except BaseException:
            pool.terminate()
            raise
    return done


def _run_step(action: Callable, root: Path, needs: dict[str, StageResult]) -> StageResult:
    return action(StageRunner(root, log=_flushed_print), needs)


def _flushed_print(text: str) -> None:
    print(text, flush=True)


# --------------------------------------------------------------------------------------------------- stopping
SIGNALS = (signal.SIGTERM, signal.SIGINT)


class RunStopped(KeyboardInterrupt):
    """The run was stopped by a signal (a KeyboardInterrupt, so that no ``except Exception`` swallows it);
    ``signum`` is the signal's number."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(f"stopped by {signal.Signals(signum).name}: its worker processes were ended; rerun the "
                         "same command to resume (finished stages are cached, a stopped one resumes from its "
                         "checkpoint)")


@contextmanager
def stop_on_signals() -> Iterator[None]:
    """Within the block, SIGTERM and SIGINT raise :class:`RunStopped` in the main thread (once: a second signal
    while the workers are being ended is ignored); the previous handlers come back after it. Outside the main
    thread (where Python cannot set handlers) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    stopping = []

    def handler(signum, _frame) -> None:
        if stopping:
            return
        stopping.append(signum)
        raise RunStopped(signum)

    previous = {signum: signal.signal(signum, handler) for signum in SIGNALS}
    try:
        yield
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)


def end_children(timeout_s: float = 5.0) -> int:
    """End the child processes this process started with ``multiprocessing`` that are still alive (SIGTERM, then
    SIGKILL after ``timeout_s``); returns how many there were."""
    children = multiprocessing.active_children()
    for child in children:
        child.terminate()
    for child in children:
        child.join(timeout_s)
        if child.is_alive():
            child.kill()
            child.join(1.0)
    return len(children)
