"""What every rehearsal against the MG400 emulator checks: each ServoP it received passes the safety layer again."""

from __future__ import annotations

import numpy as np

from simshear_gym.real.safety import MotionKind, SafetyConfig, SafetyLayer


def servo_targets(received_motion_commands: list[str]) -> list[np.ndarray]:
    """The (x, y, z, R) targets of the ServoP commands among an emulator's received motion commands."""
    return [np.array([float(v) for v in command[len("ServoP("):].split(",")[:4]])
            for command in received_motion_commands if command.lower().startswith("servop")]


def check_servo_commands_within_limits(received_motion_commands: list[str], start_pose, steps: int,
                                       period_s: float) -> None:
    """``steps`` ServoP commands, each reachable, inside the workspace box and within the step and speed limits
    from the target before (the first from ``start_pose``)."""
    safety = SafetyConfig()
    layer = SafetyLayer(safety)
    targets = servo_targets(received_motion_commands)
    assert len(targets) == steps
    previous = np.asarray(start_pose, dtype=np.float64)
    for target in targets:
        assert np.linalg.norm(target[:3] - previous[:3]) <= safety.max_step_mm
        assert safety.x_range_mm[0] <= target[0] <= safety.x_range_mm[1]
        assert safety.z_range_mm[0] <= target[2] <= safety.z_range_mm[1]
        layer.check_target(tuple(previous), tuple(target), MotionKind.SERVO, duration_s=period_s + 0.02)
        previous = target
