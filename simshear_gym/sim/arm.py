"""The arm interface the envs drive: what a follower (or leader) must offer, whatever robot it is.

Two simulated arms implement it: the 4-DoF :class:`~simshear_gym.sim.mg400_arm.SimMG400` (its tool stays level;
a tilted target is refused) and the 6-DoF :class:`~simshear_gym.sim.panda_arm.SimPanda` (any tool orientation
within its joint limits). A task places the tool by its pose in the world; how the arm gets there (closed-form or
numerical inverse kinematics) is the arm's business.

Units and frames: mm and degrees; transforms are 4x4 ``T_world_tool`` (the tool frame, e.g. the TacTip's sensor
frame, in the world). Errors: a target outside the arm's reach or joint limits raises a
:class:`~simshear_gym.robots.mg400.kinematics.KinematicsError` (``LimitError`` or ``UnreachableError``, both
``ValueError``) naming the target and the limit, and the arm keeps its motion; the envs end the episode with
``termination="arm_limit"``, as the real controller's alarm would stop the arm.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Arm(Protocol):
    """A servo-mode arm carrying a tool (see the module docstring).

    Attributes:
        tool_dof: the tool's degrees of freedom: 4 (x, y, z and the turn about the vertical: MG400) or 6.
    """

    tool_dof: int

    def T_world_tool(self) -> np.ndarray:
        """4x4 (mm) the tool now, world frame."""
        ...

    def tool_pose_mm_deg(self) -> np.ndarray:
        """(4,) the tool point x, y, z (mm) and the tool's turn R about the vertical (deg), in the arm's base
        frame: the observation's ``tcp_pose`` (what the MG400's ``GetPose`` reports with the tool set)."""
        ...

    def reset_tool(self, T_world_tool: np.ndarray) -> None:
        """Put the tool at ``T_world_tool`` at once (no motion), after checking the limits."""
        ...

    def servo_tool(self, T_world_tool: np.ndarray, duration_s: float) -> float:
        """Move the tool to ``T_world_tool`` over ``duration_s`` (slower where the speed limits need it), replacing
        any previous target; returns the motion's duration, s."""
        ...

    def advance(self, dt_s: float) -> None:
        """Move on by ``dt_s`` along the current motion; stops at the last good pose and raises at a limit."""
        ...

    def update_bodies(self) -> None:
        """Place the arm's drawn bodies at its joints (scene views only; no-op without bodies)."""
        ...


class ServoMotion:
    """What the simulated arms share: the servo motion they follow, ``(start, end, duration s, end joints)`` in the
    arm's own terms, started by :meth:`_start_motion` and followed by :meth:`advance`; the arm places itself at a
    fraction of the way (``_pass_through(start, end, fraction)``, which checks the pose and raises at a limit) and at
    the end (``_arrive(end, end_joints)``: the end was checked when the motion was commanded)."""

    _motion: tuple[np.ndarray, np.ndarray, float, np.ndarray] | None = None
    _elapsed_s = 0.0

    @property
    def moving(self) -> bool:
        return self._motion is not None

    def _start_motion(self, start: np.ndarray, end: np.ndarray, duration_s: float, end_joints: np.ndarray) -> float:
        """Replace any motion by this one; returns its duration, s."""
        self._motion = (start, end, duration_s, end_joints)
        self._elapsed_s = 0.0
        return duration_s

    def advance(self, dt_s: float) -> None:
        """Move on by ``dt_s`` along the current servo motion, checking (solving) the pose reached.

        Raises:
            LimitError, UnreachableError: the path left the limits; the arm stops at its last good pose.
        """
        if dt_s < 0.0:
            raise ValueError(f"dt_s must be >= 0, got {dt_s!r}")
        if self._motion is None:
            return
        start, end, duration, end_joints = self._motion
        self._elapsed_s += dt_s
        fraction = 1.0 if duration <= 0.0 else min(1.0, self._elapsed_s / duration)
        if fraction >= 1.0:  # the target itself was checked when the motion was commanded
            self._arrive(end, end_joints)
            self._motion = None
            return
        try:
            self._pass_through(start, end, fraction)
        except ValueError:
            self._motion = None
            raise


__all__ = ["Arm", "ServoMotion"]
