"""``SimShearTracking6D-v0``: follow a moving, tilting plate with a TacTip on a 6-DoF arm, keeping depth, place
and the sensor normal to the plate."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium.utils import EzPickle

from simshear_gym.contract import TILT_STEP_DEG, action_space_6d, action_to_move_6d
from simshear_gym.envs.base import ContactState
from simshear_gym.envs.tracking import (
    FOLLOWER_T_WORLD_BASE,
    LEADER_START_POSE_MM_DEG,
    PlateTrackingEnv,
    check_speed_mm_s,
)
from simshear_gym.envs.trajectories import COLIFT_TRAJECTORIES, TRAJECTORIES, Trajectory
from simshear_gym.sim.panda_arm import PandaArmConfig, SimPanda, axis_angle_matrix
from simshear_gym.transforms import pose_to_matrix

TRAJECTORIES_6D: tuple[str, ...] = TRAJECTORIES + COLIFT_TRAJECTORIES
"""The tracking paths, plus the co-lift env's ``circular_wave`` and ``star`` (held out for testing)."""
TRAJECTORY_CHOICES_6D: tuple[str, ...] = TRAJECTORIES_6D + ("random",)  # random: one of TRAJECTORIES per reset
FOLLOWERS: tuple[str, ...] = ("panda", "mg400")
# The Panda's base 850 mm out, 300 mm below the MG400s' J2 axes, facing the leader: the start contact sits 470 mm
# out and 240 mm up from it, mid-way in its reach, so every path (+-75 mm) and tilt (+-20 deg) stays well inside.
PANDA_T_WORLD_BASE = pose_to_matrix(np.array([850.0, 0.0, -300.0, 0.0, 0.0, 180.0]))
PANDA_MOUNT_RZ_DEG = -45.0  # the TacTip turned on panda_link8 so that the start needs joint 7 mid-range (45 deg)


def tilt_matrix(rx_deg: float, ry_deg: float) -> np.ndarray:
    """4x4 rotation by ``rx_deg`` about x, then ``ry_deg`` about the fixed y (extrinsic, as the labels' poses)."""
    cx, sx = math.cos(math.radians(rx_deg)), math.sin(math.radians(rx_deg))
    cy, sy = math.cos(math.radians(ry_deg)), math.sin(math.radians(ry_deg))
    matrix = np.eye(4)
    matrix[:3, :3] = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]]) @ np.array(
        [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    return matrix


class SimShearTracking6DEnv(PlateTrackingEnv):
    """Keep a TacTip in contact with, and normal to, a plate that a leader moves along a path while tilting it.

    The scene of ``SimShearTracking-v0`` (:class:`~simshear_gym.envs.tracking.SimShearTrackingEnv`): a leader MG400
    moves a 120 x 120 mm plate along ``trajectory``, turning it about the vertical by up to 15 deg; here the plate
    sits on a two-axis tilt stage on the leader's bracket (pivot at the face's centre) that tilts it by
    ``Rx = a_x sin(2 pi s)`` about the plate's x and ``Ry = a_y sin(4 pi s)`` about its y, ``s`` in [0, 1] the
    fraction of the path travelled (level at the start and the end; ``a_x = a_y = tilt_deg`` = 20 deg nominal).
    The **follower** (``follower="panda"``, default) is a simulated Franka Panda
    (:class:`~simshear_gym.sim.panda_arm.SimPanda`: inverse kinematics, joint limits, servo mode) carrying the
    TacTip 95 mm beyond its flange; it starts touching the plate's centre at the reference depth, normal to it.
    Its task: keep that depth, its place on the plate and the sensor normal to the plate. With
    ``follower="mg400"`` the follower is the tracking env's level MG400 (the 4-DoF baseline: it cannot tilt).

    **Action** ``Box(-1, 1, (6,), float32)`` (Panda; the MG400 takes the tracking env's 4-D action): a relative
    move of the sensor in its own frame per step, rotations about the dome's apex
    (:func:`~simshear_gym.contract.action_to_move_6d`):

    ======  ============================  ======  =====================================
    index   meaning                       unit    full scale
    ======  ============================  ======  =====================================
    0, 1    dx, dy (in the plate plane)   mm      1 mm per step (``ActionScale``)
    2       dz (+: into the plate)        mm      1 mm per step
    3       dRz about the sensor axis     deg     2 deg per step
    4, 5    dRx, dRy: tilt about the      deg     ``tilt_step_deg`` (1) per step
            sensor's x, y axes
    ======  ============================  ======  =====================================

    NaN, wrong shape or values outside [-1, 1] raise ``ValueError``.

    **Observation**: the tracking env's (:func:`~simshear_gym.contract.observation_space`, every ``observation``
    and ``obs_mode``): the TacTip image (translated in ``"real"``), ``tcp_pose`` (apex x, y, z mm in the follower's
    base frame and the sensor's turn about the base's vertical, deg), the estimate, and in the oracle modes
    ``true_pose_shear`` (depth, shear x, y, shear Rz). The estimator of the estimate observation is fed the first
    four components of the move.

    **Reward, termination, truncation**: as ``SimShearTracking-v0`` (the contact error: distance of the TCP from
    its start point carried with the tilting face). ``info`` holds the tracking env's entries and
    ``normal_error_deg`` (angle between the sensor's axis and the plate's inward normal), ``sensor_tilt_deg``
    (Rx, Ry: the sensor's tilt in the plate's work frame, as the GDNN's ``rx_deg``, ``ry_deg`` read it) and
    ``plate_tilt_deg`` (the stage's Rx, Ry).

    Args:
        trajectory: one of :data:`TRAJECTORIES_6D` (``circle``, ``tilted_square``, ``spiral``, ``loop``; the test
            paths ``circular_wave``, ``star``) or ``random`` (one of the first four per reset).
        follower: ``"panda"`` (6-DoF) or ``"mg400"`` (4-DoF baseline).
        tilt_deg: the tilt amplitude (both axes), deg, in [0, 20].
        tilt_step_deg: full-scale tilt rate of the action, deg per step.
        panda_config: the Panda's speeds and IK tolerances.
        speed_mm_s, randomise: as the tracking env; ``randomise`` also draws each tilt amplitude (x0.5-1, either
            sign).
        obs_mode, image_size_px, control_rate_hz, render_mode, reference_depth_mm, observation, history,
            estimator, ...: see :class:`~simshear_gym.envs.base.SimShearEnv`.
        options of ``reset``: ``{"start_offset_mm": (x, y)}`` as the tracking env.

    Version history: v0 (initial).
    """

    def __init__(self, trajectory: str = "circle", follower: str = "panda", obs_mode: str = "real",
                 image_size_px: int = 128, control_rate_hz: float = 10.0, render_mode: str | None = None,
                 reference_depth_mm: float = 4.0, speed_mm_s: float = 4.0, tilt_deg: float = 20.0,
                 tilt_step_deg: float = TILT_STEP_DEG, randomise: bool = False,
                 panda_config: PandaArmConfig = PandaArmConfig(), **base_kwargs) -> None:
        EzPickle.__init__(self, trajectory=trajectory, follower=follower, obs_mode=obs_mode,
                          image_size_px=image_size_px, control_rate_hz=control_rate_hz, render_mode=render_mode,
                          reference_depth_mm=reference_depth_mm, speed_mm_s=speed_mm_s, tilt_deg=tilt_deg,
                          tilt_step_deg=tilt_step_deg, randomise=randomise, panda_config=panda_config,
                          **base_kwargs)
        if trajectory not in TRAJECTORY_CHOICES_6D:
            raise ValueError(f"unknown trajectory {trajectory!r}; expected one of {TRAJECTORY_CHOICES_6D}")
        if follower not in FOLLOWERS:
            raise ValueError(f"unknown follower {follower!r}; expected one of {FOLLOWERS}")
        speed_mm_s = check_speed_mm_s(speed_mm_s)
        if not (isinstance(tilt_deg, (int, float)) and 0.0 <= tilt_deg <= 20.0):
            raise ValueError(f"tilt_deg must be within [0, 20] deg, got {tilt_deg!r}")
        if not (isinstance(tilt_step_deg, (int, float)) and math.isfinite(tilt_step_deg) and tilt_step_deg > 0):
            raise ValueError(f"tilt_step_deg must be > 0, got {tilt_step_deg!r}")
        self.trajectory_name = trajectory
        self.follower_name = follower
        self.speed_mm_s = speed_mm_s
        self.tilt_deg = float(tilt_deg)
        self.tilt_step_deg = float(tilt_step_deg)
        self.randomise = bool(randomise)
        self.panda_config = panda_config
        self.trajectory: Trajectory | None = None
        self._tilt_amplitude_deg = (self.tilt_deg, self.tilt_deg)
        self._plate_tilt_deg = (0.0, 0.0)
        super().__init__(obs_mode=obs_mode, image_size_px=image_size_px, control_rate_hz=control_rate_hz,
                         render_mode=render_mode, reference_depth_mm=reference_depth_mm, **base_kwargs)
        if follower == "panda":
            self.action_space = action_space_6d()

    # ------------------------------------------------------------------ hooks
    def _build_scene(self) -> None:
        self._build_plate()
        if self.follower_name == "mg400":
            self._add_follower(FOLLOWER_T_WORLD_BASE, self._follower_pose_at((0.0, 0.0)))
        else:
            T_flange_sensor = pose_to_matrix(np.array([0.0, 0.0, self.mount.tcp_offset_mm, 0.0, 0.0,
                                                       PANDA_MOUNT_RZ_DEG + self.mount.mount_rz_deg]))
            self._use_follower(SimPanda(self.world, PANDA_T_WORLD_BASE, self._sensor_start((0.0, 0.0)),
                                        T_flange_sensor, self.panda_config, bodies=self.render_mode is not None))

    def _reset_scene(self, rng: np.random.Generator, options: dict | None) -> None:
        config, offset = self._draw_path(rng)  # then the tilt amplitudes, from the same rng
        amplitude = (self.tilt_deg, self.tilt_deg)
        if self.randomise:
            amplitude = tuple(float(v) for v in self.tilt_deg * rng.uniform(0.5, 1.0, 2) * rng.choice([-1, 1], 2))
        offset = self._start_offset(options, offset)
        self.trajectory = Trajectory(config)
        self._tilt_amplitude_deg = amplitude
        self._plate_tilt_deg = (0.0, 0.0)
        self.leader.reset(LEADER_START_POSE_MM_DEG)
        self.follower.reset_tool(self._sensor_start(offset))

    def tilt_at(self, time_s: float) -> tuple[float, float]:
        """The stage's (Rx, Ry) deg at ``time_s``: smooth along the path, level at its start and end."""
        arc = min(max(time_s, 0.0) * self.trajectory.config.speed_mm_s, self.trajectory.length_mm)
        fraction = arc / self.trajectory.length_mm
        return (self._tilt_amplitude_deg[0] * math.sin(2.0 * math.pi * fraction),
                self._tilt_amplitude_deg[1] * math.sin(4.0 * math.pi * fraction))

    def _command_scene(self, time_s: float, dt_s: float) -> None:
        self.leader.servo_tool(self._T_world_plate_at(time_s), dt_s)
        self._plate_tilt_deg = self.tilt_at(time_s)  # the stage reaches it within the period, as the arm

    def _T_world_face(self) -> np.ndarray:
        return self.leader.T_world_tool() @ tilt_matrix(*self._plate_tilt_deg)

    # ------------------------------------------------------------- 6-DoF moves
    def _action_to_move(self, action) -> np.ndarray:
        if self.follower_name == "mg400":
            return super()._action_to_move(action)
        return action_to_move_6d(action, self.action_scale, self.tilt_step_deg)

    def _sensor_target(self, T_world_sensor: np.ndarray, move: np.ndarray) -> np.ndarray:
        """A 6-DoF move ``(dx, dy, dz mm, dRz, dRx, dRy deg)``: translation in the sensor frame, rotation (vector
        ``(dRx, dRy, dRz)``) about the apex; a 4-DoF move as the base."""
        if len(move) == 4:
            return super()._sensor_target(T_world_sensor, move)
        T_move = np.eye(4)
        T_move[:3, :3] = axis_angle_matrix(np.radians([move[4], move[5], move[3]]))
        T_move[:3, 3] = move[:3]
        return T_world_sensor @ T_move

    def _observation(self, state: ContactState, move: np.ndarray | None) -> dict[str, np.ndarray]:
        return super()._observation(state, None if move is None else move[:4])

    def _info(self, state: ContactState, termination: str) -> dict[str, Any]:
        info = super()._info(state, termination)
        sensor_axis = state.T_world_sensor[:3, 2]
        face_normal = self._T_world_face()[:3, 2]
        info["normal_error_deg"] = math.degrees(math.acos(max(-1.0, min(1.0, -float(sensor_axis @ face_normal)))))
        info["sensor_tilt_deg"] = state.pose_work[3:5].copy()
        info["plate_tilt_deg"] = np.array(self._plate_tilt_deg)
        info["trajectory"] = self.trajectory.config.name if self.trajectory is not None else ""
        return info

    def close(self) -> None:
        if isinstance(self.follower, SimPanda):
            self.follower.close()
        super().close()
