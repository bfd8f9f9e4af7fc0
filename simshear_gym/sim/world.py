"""The PyBullet world: the one owner of the physics client. Robots, sensors and stimuli receive a ``World``
and call ``world.client``; nothing in the package calls the global ``pybullet`` module state."""

from __future__ import annotations

import contextlib
import os
import sys
from dataclasses import dataclass
from typing import Self

import pybullet
from pybullet_utils.bullet_client import BulletClient


@dataclass(frozen=True)
class WorldConfig:
    """Physics settings, defined once.

    Attributes:
        time_step_s: simulation step (Tactile Gym's 1/240 s).
        solver_iterations: constraint solver iterations per step.
        gravity_mps2: gravity along world -z.
    """

    time_step_s: float = 1.0 / 240.0
    solver_iterations: int = 150
    gravity_mps2: float = 9.81

    def __post_init__(self) -> None:
        if not 0 < self.time_step_s <= 0.1:
            raise ValueError(f"time_step_s must be in (0, 0.1] s, got {self.time_step_s}")
        if self.solver_iterations < 1:
            raise ValueError(f"solver_iterations must be >= 1, got {self.solver_iterations}")


@contextlib.contextmanager
def _quiet_stdout():
    """Silence the C library's stdout (PyBullet prints ``argv[0]=`` on every connection) for the block."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError):  # no real stdout file descriptor (some test runners): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


class ClosedOnExit:
    """``with`` support for an owner of a resource: the block's end calls its ``close()``."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class World(ClosedOnExit):
    """A headless (DIRECT) PyBullet physics client with fixed settings.

    Use as a context manager or call :meth:`close`; a closed world refuses further use.
    """

    def __init__(self, config: WorldConfig = WorldConfig()) -> None:
        self.config = config
        with _quiet_stdout():
            self._client: BulletClient | None = BulletClient(connection_mode=pybullet.DIRECT)
        self._client.setTimeStep(config.time_step_s)
        self._client.setPhysicsEngineParameter(numSolverIterations=config.solver_iterations)
        self._client.setGravity(0.0, 0.0, -config.gravity_mps2)

    @property
    def client(self) -> BulletClient:
        if self._client is None:
            raise RuntimeError("this World is closed")
        return self._client

    def step(self, n_steps: int = 1) -> None:
        """Advance the physics by ``n_steps`` time steps."""
        for _ in range(n_steps):
            self.client.stepSimulation()

    def close(self) -> None:
        if self._client is not None:
            self._client.disconnect()
            self._client = None
