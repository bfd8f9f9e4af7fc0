"""``SimShearTracking-v0``: follow a moving plate with a TacTip, keeping depth and place."""

from __future__ import annotations

import math

import numpy as np
from gymnasium.utils import EzPickle

from simshear_gym.envs.base import SimShearEnv, pybullet_pose_fast
from simshear_gym.envs.trajectories import COLIFT_TRAJECTORIES, TRAJECTORIES, Trajectory, TrajectoryConfig
from simshear_gym.sim import stimuli
from simshear_gym.sim.mg400_arm import SimMG400
from simshear_gym.transforms import pose_to_matrix, rz_matrix

TRAJECTORY_CHOICES: tuple[str, ...] = TRAJECTORIES + COLIFT_TRAJECTORIES + ("random",)
"""The tracking paths, the co-lift env's ``circular_wave`` and ``star`` (held out: ``random`` never draws them, so
a policy trained on random paths is tested on them unseen), and ``random``."""

# Scene layout, world frame (mm): z up, z = 0 at both arms' J2 axes (their base frames' origin height).
LEADER_T_WORLD_BASE = np.eye(4)
# Both flanges start 310 mm out, mid-way in the MG400's reach (about 200-430 mm at these heights), so that every
# randomised trajectory (up to 75 mm either way) stays inside both arms' limits.
FOLLOWER_T_WORLD_BASE = pose_to_matrix(np.array([690.0, 0.0, 0.0, 0.0, 0.0, 180.0]))
LEADER_START_POSE_MM_DEG = np.array([310.0, 0.0, -40.0, 0.0])  # leader flange, its base frame
# The plate's top-face frame on the leader's flange: 70 mm out along the flange's x, 20 mm below it, turned a
# half turn so that the plate's x (and the work frame's x) runs along the follower's flange x at the start.
T_FLANGE_PLATE = pose_to_matrix(np.array([70.0, 0.0, -20.0, 0.0, 0.0, 180.0]))
PLATE = stimuli.FlatSurface(size_mm=(120.0, 120.0, 10.0))


def check_speed_mm_s(speed_mm_s) -> float:
    """The plate's speed as a float; raises ``ValueError`` unless it is a finite number > 0."""
    if not (isinstance(speed_mm_s, (int, float)) and math.isfinite(speed_mm_s) and speed_mm_s > 0):
        raise ValueError(f"speed_mm_s must be > 0, got {speed_mm_s!r}")
    return float(speed_mm_s)


class PlateTrackingEnv(SimShearEnv):
    """What the tracking envs share: the leader MG400 moving :data:`PLATE` along a trajectory (the subclasses set
    ``trajectory_name``, ``speed_mm_s`` and ``randomise``, and place the follower)."""

    def _build_plate(self) -> None:
        """The leader with the plate at its start pose, and the plate's body."""
        self.leader: SimMG400 = self._add_arm(LEADER_T_WORLD_BASE, LEADER_START_POSE_MM_DEG, T_FLANGE_PLATE)
        self._T_world_plate_start = self.leader.T_world_tool()
        self._plate_body = stimuli.spawn(self.world, PLATE, self._T_world_plate_start)
        self.face_half_extents_mm = (PLATE.size_mm[0] / 2.0, PLATE.size_mm[1] / 2.0)

    def _sensor_start(self, offset_work_mm: tuple[float, float]) -> np.ndarray:
        """The sensor on the level start plate at ``offset`` (work frame), at the reference depth."""
        return self.T_world_sensor_on_face(self._T_world_plate_start, offset_work_mm[0], offset_work_mm[1],
                                           self.reference_depth_mm)

    def _follower_pose_at(self, offset_work_mm: tuple[float, float]) -> np.ndarray:
        """The MG400 follower's flange pose that puts the sensor at :meth:`_sensor_start`."""
        return self.flange_pose_for_sensor(FOLLOWER_T_WORLD_BASE, self._sensor_start(offset_work_mm))

    def _draw_path(self, rng: np.random.Generator) -> tuple[TrajectoryConfig, tuple[float, float]]:
        """The reset's path (``random``: one of :data:`TRAJECTORIES`) and the follower's start place on the plate
        (work frame, mm); with ``randomise``, the scale, speed, rotation and start place drawn from ``rng``."""
        name = self.trajectory_name
        if name == "random":
            name = TRAJECTORIES[int(rng.integers(len(TRAJECTORIES)))]
        scale, speed, rotation, offset = 1.0, self.speed_mm_s, TrajectoryConfig().rotation_deg, (0.0, 0.0)
        if self.randomise:
            scale = float(rng.uniform(0.7, 1.3))
            speed *= float(rng.uniform(0.7, 1.3))
            rotation *= float(rng.uniform(-1.0, 1.0))
            offset = tuple(float(v) for v in rng.uniform(-10.0, 10.0, 2))
        return TrajectoryConfig(name, scale=scale, speed_mm_s=speed, rotation_deg=rotation), offset

    @staticmethod
    def _start_offset(options: dict | None, offset: tuple[float, float]) -> tuple[float, float]:
        """``options["start_offset_mm"]`` (checked) where given, else ``offset``."""
        if options and "start_offset_mm" in options:
            offset = tuple(float(v) for v in options["start_offset_mm"])
            if len(offset) != 2 or not all(math.isfinite(v) and abs(v) <= 40.0 for v in offset):
                raise ValueError(f"options['start_offset_mm'] must be (x, y) within +-40 mm, got {offset}")
        return offset

    def _T_world_plate_at(self, time_s: float) -> np.ndarray:
        dx, dy, dz, dr = self.trajectory.offset_at(time_s)
        T_world_plate = self._T_world_plate_start @ rz_matrix(dr)
        T_world_plate[:3, 3] = self._T_world_plate_start[:3, 3] + (dx, dy, dz)
        return T_world_plate

    def _sync_scene(self) -> None:
        # stimuli.move without its scipy conversion (this runs every step)
        T_world_box = self._T_world_face()
        T_world_box[:3, 3] += T_world_box[:3, :3] @ PLATE.box_centre_mm()
        self.world.client.resetBasePositionAndOrientation(self._plate_body, *pybullet_pose_fast(T_world_box))


class SimShearTrackingEnv(PlateTrackingEnv):
    """Keep a TacTip in contact with a plate that a leader MG400 moves along a trajectory.

    Two MG400s face each other 690 mm apart. The **leader** holds a flat 120 x 120 mm plate, top face up, on a
    bracket 70 mm beyond and 20 mm below its flange, and moves it along ``trajectory`` (see
    :mod:`simshear_gym.envs.trajectories`: ``circle``, ``tilted_square``, ``spiral``, ``loop``, each turning the
    plate about the vertical by up to 15 deg; the plate stays level). The **follower** carries the TacTip
    pointing down (``TacTipMount``: apex 95 mm below the flange) and starts touching the plate at the reference
    depth. Its task: keep that depth and its place on the plate (variables: depth z, shear x, shear y, shear Rz).
    Both arms are kinematic MG400s in servo mode (:class:`~simshear_gym.sim.mg400_arm.SimMG400`): each step
    sends one ServoP to each, reached within the control period.

    **Action** ``Box(-1, 1, (4,), float32)``: a relative move of the sensor in its own frame per step:

    ======  ============================  ======  =====================================
    index   meaning                       unit    full scale (``ActionScale`` default)
    ======  ============================  ======  =====================================
    0, 1    dx, dy (in the plate plane)   mm      1 mm per step
    2       dz (+: into the plate)        mm      1 mm per step
    3       dRz about the sensor axis     deg     2 deg per step
    ======  ============================  ======  =====================================

    NaN, wrong shape or values outside [-1, 1] raise ``ValueError``.

    **Observation** ``Dict``, by ``observation`` (:func:`~simshear_gym.contract.observation_space`, the same in
    ``RealTactileEnv``), k = ``history`` (default 1), oldest first:

    ===================  ==========================  ============================================================
    key                  space                       meaning
    ===================  ==========================  ============================================================
    ``tactile``          Box uint8 (k, S, S)         ``observation`` "tactile" (default) or "tactile+estimate":
                                                     the last k TacTip images, S = ``image_size_px`` (128 or 64);
                                                     shPix2pix translated (``obs_mode`` "real", "oracle_real")
                                                     or raw depth ("sim", "oracle"; 255 = 14.5 mm penetration)
    ``tcp_pose``         Box float32 (4,)            "tactile" only: follower TCP (dome apex) x, y, z mm and
                                                     flange R deg, in the follower's base frame (as ``GetPose``
                                                     with the tool set); absolute, in a +-1000 box: for a
                                                     learner without ``VecNormalize`` wrap the env in
                                                     ``envs.wrappers.RelativeTcpPose`` (the move since reset,
                                                     in [-1, 1])
    ``estimate``         Box float32 (16 k,) in      "estimate" or "tactile+estimate": per image, the servo
                         [-4, 4]                     controller's estimator (the shipped ``surface`` GDNN +
                                                     Bayesian filter, fed the commanded moves; ``estimator=``)
                                                     of (depth, shear x, shear y, shear Rz): GDNN reading mean,
                                                     its std, filter mean, filter std; means as (value -
                                                     (reference depth, 0, 0, 0)) / (2 mm, 7.5 mm, 7.5 mm,
                                                     7.5 deg) clipped to +-4, stds as clip(std / that, 0, 2) - 1
                                                     (:func:`~simshear_gym.contract.estimate_features`)
    ``last_action``      Box float32 (4,) in         "estimate+action" only (with ``estimate``): the move
                         [-1, 1]                     commanded since the previous image over the full scale
    ``true_pose_shear``  Box float32 (4,)            oracle modes only: depth (label convention: the plate's face
                                                     at 2.2 mm), shear x, y (mm), shear Rz (deg), sensor frame
    ===================  ==========================  ============================================================

    **Reward** (``RewardConfig``), ``e`` the contact error: ``1 - min(e / 5 mm, 1) + exp(-(e / 1 mm)^2)
    - 1[not in contact] - 10 * 1[the step ends the episode]``: in [0, 2] while in contact (2 on target), so
    holding on always beats ending early; the Gaussian term rewards the last fraction of a millimetre.

    **Contact error** ``info["contact_error_mm"]`` every step: the distance between the follower's TCP and its
    target point: where the TCP was at reset (on the plate at the reference depth), carried along with the
    plate. ``info`` also holds ``rz_error_deg``, ``in_contact``, ``penetration_mm``, ``depth_mm``,
    ``shear_sensor_mm_deg`` (6,), ``time_s``, ``steps_out_of_contact``, ``termination`` (reason or ``""``),
    ``trajectory``, ``sensor_world_mm`` and ``target_world_mm`` (the TCP and its target point, world frame, for
    path figures) and, when an arm refused a target, ``arm_error``.

    **Termination** (``TerminationConfig``): the sensor lifts > 1 mm off the plate or leaves it
    (``"contact_lost"``), contact error > 15 mm (``"contact_error"``), penetration > 5 mm (``"too_deep"``), or
    an arm refuses a target outside its limits (``"arm_limit"``; the step returns normally). **Truncation**:
    ``max_episode_steps`` of the registration (500 steps = 50 s at 10 Hz; every default trajectory ends
    within 48 s, after which the plate holds still).

    **Render modes** (``render_mode``): ``"rgb_array"``: ``render()`` returns uint8 (180, 420, 3), the scene (arms,
    TacTip, the plate) beside the newest tactile image; ``"human"``: that frame in a window, refreshed on every
    ``reset`` and ``step`` at the control rate (needs a display: ``xvfb-run`` on a machine without one); None
    (default): no scene bodies, the fastest steps.

    Args:
        trajectory: one of ``circle``, ``tilted_square``, ``spiral``, ``loop``, ``random`` (one of those four drawn
            per reset), or the held-out test paths ``circular_wave`` and ``star`` (the plate waves up and down,
            or draws a star in the vertical y-z plane: the follower tracks depth as well as place).
        obs_mode, image_size_px, control_rate_hz, render_mode, reference_depth_mm, observation, history,
            estimator, ...: see :class:`~simshear_gym.envs.base.SimShearEnv` (defaults: ``"real"``, 128, 10 Hz,
            None, 4.0 mm, ``"tactile"``, 1; ``observation="estimate"`` needs ``estimator=
            simshear_gym.control.env_estimator.env_estimator``).
        speed_mm_s: the plate's speed along its path.
        randomise: per reset, draw the trajectory's scale (x0.7-1.3), speed (x0.7-1.3), rotation (-1..1 x 15 deg)
            and the follower's start place on the plate (+-10 mm in x and y) from the reset's seed.
        options of ``reset``: ``{"start_offset_mm": (x, y)}`` sets the start place (work frame of the plate).

    Version history: v0 (initial; before the first release: the ``observation`` / ``history`` arguments, and the
    reward's error term capped at 1 with the precision and early-end terms added, where it was ``1 - min(e / 5 mm,
    2) - 1[not in contact]``).
    """

    def __init__(self, trajectory: str = "circle", obs_mode: str = "real", image_size_px: int = 128,
                 control_rate_hz: float = 10.0, render_mode: str | None = None, reference_depth_mm: float = 4.0,
                 speed_mm_s: float = 4.0, randomise: bool = False, **base_kwargs) -> None:
        EzPickle.__init__(self, trajectory=trajectory, obs_mode=obs_mode, image_size_px=image_size_px,
                          control_rate_hz=control_rate_hz, render_mode=render_mode,
                          reference_depth_mm=reference_depth_mm, speed_mm_s=speed_mm_s, randomise=randomise,
                          **base_kwargs)
        if trajectory not in TRAJECTORY_CHOICES:
            raise ValueError(f"unknown trajectory {trajectory!r}; expected one of {TRAJECTORY_CHOICES}")
        self.trajectory_name = trajectory
        self.speed_mm_s = check_speed_mm_s(speed_mm_s)
        self.randomise = bool(randomise)
        self.trajectory: Trajectory | None = None
        super().__init__(obs_mode=obs_mode, image_size_px=image_size_px, control_rate_hz=control_rate_hz,
                         render_mode=render_mode, reference_depth_mm=reference_depth_mm, **base_kwargs)

    # ------------------------------------------------------------------ hooks
    def _build_scene(self) -> None:
        self._build_plate()
        self._add_follower(FOLLOWER_T_WORLD_BASE, self._follower_pose_at((0.0, 0.0)))

    def _reset_scene(self, rng: np.random.Generator, options: dict | None) -> None:
        config, offset = self._draw_path(rng)
        offset = self._start_offset(options, offset)
        self.trajectory = Trajectory(config)
        self.leader.reset(LEADER_START_POSE_MM_DEG)
        self.follower.reset(self._follower_pose_at(offset))

    def _command_scene(self, time_s: float, dt_s: float) -> None:
        self.leader.servo_tool(self._T_world_plate_at(time_s), dt_s)

    def _T_world_face(self) -> np.ndarray:
        return self.leader.T_world_tool()

    def _task_info(self) -> dict:
        return {"trajectory": self.trajectory.config.name if self.trajectory is not None else ""}
