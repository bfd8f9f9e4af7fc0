"""A stopped run stops all of its processes: SIGTERM (a scheduler, ``kill``) and SIGINT (Ctrl-C) become
:class:`RunStopped` in the main process, so the code that owns the worker processes ends them on the way out (the
step graph's pool: :func:`~simshear_gym.pipelines.schedule.run_steps`; the collect stage's rendering pool), and
:func:`end_children` ends whatever child is left.

Python's default for SIGTERM is to die at once, skipping every ``finally``: the workers of a ``multiprocessing``
pool then live on as orphans, still training and writing into the run folder. Nothing a stopped run leaves breaks
a rerun: a stage counts as done only once its record is written (:mod:`~simshear_gym.pipelines.stages`), and
every file is written atomically, so the rerun resumes the stopped stages from their checkpoints.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

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
