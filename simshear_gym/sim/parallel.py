"""Where chunks of embarrassingly parallel work run: plain processes on this machine, or Ray tasks.

``map_chunks(function, chunks, workers)`` is ``[function(c) for c in chunks]`` in ``workers`` processes (forked
where the platform allows it); with ``ray_address`` each chunk is a Ray task (one CPU) instead:

- ``"local"``: a Ray started on this machine with ``workers`` CPUs (and stopped afterwards);
- ``"auto"``: the cluster that ``ray start --head`` / ``ray start --address HEAD`` started here;
- ``"HOST:PORT"`` (a head's GCS address) or ``"ray://HOST:10001"`` (Ray Client): that cluster.

A Ray session that is already running (``ray.init`` by the caller, or :func:`ray_session` around several calls)
is used as it is and left running. The results come back in the order of ``chunks`` whatever the executor, so a
caller whose chunks are pure functions of their input gets the same output from every executor.

Ray is an optional extra (``pip install -e ".[ray]"``), imported only when an address is given. Functions and
chunks must pickle; a cluster's nodes need simshear-gym installed (the same version) to import the function.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator, Sequence
from typing import Any

LOCAL = "local"
RAY_EXTRA = 'pip install -e ".[ray]"'


class ExecutorError(RuntimeError):
    """Ray is not installed, or the Ray cluster at the given address cannot be reached."""


def check_ray_address(ray_address: str | None) -> None:
    """Raise ``ValueError`` unless ``ray_address`` is None or a non-empty address without spaces."""
    if ray_address is not None and (not isinstance(ray_address, str) or not ray_address.strip()
                                    or any(c.isspace() for c in ray_address)):
        raise ValueError(f"ray address {ray_address!r}: expected 'local', 'auto', HOST:PORT or ray://HOST:PORT")


def map_chunks(function: Callable[[Any], Any], chunks: Sequence[Any], workers: int,
               ray_address: str | None = None) -> list:
    """``[function(c) for c in chunks]``, in order: in ``workers`` processes (in this process when ``workers``
    is 1 or there is one chunk), or as Ray tasks at ``ray_address`` (see the module docstring).

    Process workers are forked where the platform allows it (start-up in milliseconds); each builds what it
    needs itself (a PyBullet scene, say), so nothing stateful crosses a process boundary.
    """
    if ray_address is not None:
        with ray_session(ray_address, num_cpus=workers) as ray:
            task = ray.remote(num_cpus=1)(_call)
            return ray.get([task.remote(function, chunk) for chunk in chunks])
    if workers <= 1 or len(chunks) <= 1:
        return [function(chunk) for chunk in chunks]
    import multiprocessing

    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    with multiprocessing.get_context(method).Pool(min(workers, len(chunks)), initializer=quiet_worker) as pool:
        return pool.map(function, chunks)


def quiet_worker() -> None:
    """A pool worker's signal handling: a forked worker inherits its parent's handlers (a command's SIGTERM /
    SIGINT handler that raises in the main thread), so the pool's terminate (SIGTERM) would print a traceback per
    worker. SIGTERM ends a worker at once; SIGINT (Ctrl-C reaches the whole process group) is left to the parent,
    which ends its pool."""
    import signal

    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _call(function: Callable[[Any], Any], chunk: Any) -> Any:
    """One Ray task (``ray.remote`` takes Python functions only; this one takes builtins and callables too)."""
    return function(chunk)


@contextlib.contextmanager
def ray_session(ray_address: str, num_cpus: int | None = None) -> Iterator[Any]:
    """The ``ray`` module, connected for the duration of the block.

    Uses a running session as it is (and leaves it running); otherwise starts a local Ray with ``num_cpus``
    CPUs (``"local"``) or connects to the cluster at ``ray_address``, and shuts it down (this process's
    connection; a cluster keeps running) when the block ends.
    """
    check_ray_address(ray_address)
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    try:
        if ray_address == LOCAL:
            ray.init(num_cpus=num_cpus, include_dashboard=False, logging_level=logging.WARNING)
        else:
            ray.init(address=ray_address, logging_level=logging.WARNING)
    except Exception as error:  # ray raises ConnectionError, ValueError or RuntimeError depending on the failure
        raise ExecutorError(
            f"ray address {ray_address!r}: could not start or join Ray ({type(error).__name__}: {error}); expected "
            "'local', or 'auto' / HOST:PORT of a running cluster (`ray start --head` on the head node)"
        ) from error
    try:
        yield ray
    finally:
        ray.shutdown()


def import_ray() -> Any:
    """The ``ray`` module, or an :class:`ExecutorError` that names the extra to install."""
    try:
        import ray
    except ImportError as error:
        raise ExecutorError(f"running on Ray needs the optional ray extra: {RAY_EXTRA} (ray>=2.9,<3); "
                            "leave out the Ray address to use plain processes") from error
    return ray
