"""Run a pipeline's training steps as a graph: a step starts once the steps it needs are done, up to ``jobs`` at a
time, each in a fresh worker process (``jobs`` = 1: one after another in this process).

A step is a :class:`Step`: its name, the steps it needs and its action, ``action(runner, done) -> StageResult``,
where ``runner`` is a :class:`~simshear_gym.pipelines.stages.StageRunner` over the run folder and ``done`` holds
the records of the steps it needs. Actions must pickle (module-level functions, or :func:`functools.partial` of
them), since a worker process runs them. Among the steps that are ready, the one with the longest chain of
``cost`` after it starts first, so the critical path (real-image GDNN -> pose-consistency generators -> GDNN on
translated images) is never left waiting behind side branches.
"""

from __future__ import annotations

import multiprocessing
import queue
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from simshear_gym.pipelines.stages import StageResult, StageRunner, StageStopped


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
    A worker's cap stop (:class:`~simshear_gym.pipelines.stages.StageStopped`) or bad-input error (ValueError,
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
