"""``SimShearPush-v0``: push an object across a table to a target along a straight path, by touch."""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle

from simshear_gym.contract import TRUE_POSE_SHEAR_LIMIT, HorizontalTacTipMount, ServoHints, goal_space, push_goal
from simshear_gym.envs.base import ContactState, SimShearEnv, TerminationConfig, pybullet_pose_fast
from simshear_gym.sim.pushing import (
    HEIGHT_MM,
    PUSH_SHAPES,
    PushedObject,
    PushPhysicsConfig,
    push_shape,
    spawn_push_object,
)
from simshear_gym.sim.replay import SURFACE_DEPTH_MM
from simshear_gym.transforms import invert, pose_from_matrix_fast

SHAPE_CHOICES: tuple[str, ...] = PUSH_SHAPES + ("random",)
FOLLOWER_T_WORLD_BASE = np.eye(4)
"""The follower's base at the world origin (z = 0 at its J2 axis)."""
START_WORLD_MM = np.array([340.0, -70.0])
"""The object's centre at reset (world x, y); the path runs from it, the sensor pushes it along world +y first."""
TABLE_Z_MM = -80.0
"""The table's top: the horizontal TacTip's axis (60 mm below a flange at z = 0) meets the 40 mm object mid-height."""
ORACLE_VARIABLES: tuple[str, ...] = ("z_mm", "shear_x_mm", "face_yaw_deg", "bearing_deg")
"""``true_pose_shear`` of the oracle modes: the depth (labels' z), the shear along the face (sensor x), the face's
turn against the sensor about the vertical (the labels' Ry: + turns the face's normal towards sensor -x... see
:meth:`SimShearPushEnv._face_yaw_deg`) and the path's bearing from the sensor's axis (deg, + towards sensor +x)."""
PUSH_TERMINATION = TerminationConfig(lost_contact_mm=5.0, max_contact_error_mm=40.0, max_penetration_mm=4.0)
"""Contact is lost when the dome is 5 mm off the object; the object strays 40 mm off the path; 4 mm deep is too
deep (the labels' depth range ends at 5.5 mm, 3.3 mm into the face)."""


class SimShearPushEnv(SimShearEnv):
    """Push an object across a table to a target along a straight path, with a horizontal TacTip on the MG400
    follower (Tactile Gym's object pushing, with shear).

    The object (:mod:`simshear_gym.sim.pushing`: ``cube``, ``cylinder`` or ``prism``, 40 mm tall) lies on a table
    in front of the follower, whose TacTip lies horizontally (:class:`~simshear_gym.contract.HorizontalTacTipMount`,
    as in ``SimShearCoLift-v0``) and touches the object's face. The target lies ``path_length_mm`` away, at
    ``path_angle_deg`` from the first push's direction; the path is the straight line from the object's start to
    the target. The object moves quasi-statically (:class:`~simshear_gym.sim.pushing.PushedObject`): it slides
    when the contact's force reaches the table's friction, turns when pushed off its centre of pressure, and the
    skin sticks or slips on it. The images are the surface data's (the shipped surface shPix2pix and GDNN): the
    depth and the face's tilt show in them, and the shear is the skin's stretch, which shows the object turning
    and slipping before the tilt does.

    **Action**: as ``SimShearCoLift-v0``'s (dx, dy, dz mm in the sensor frame, dRz deg about the vertical, per step,
    [-1, 1] of 1 mm, 1 mm, 1 mm, 2 deg): sensor z is the pushing direction, x horizontal along the face, y down.

    **Observation**: as ``SimShearTracking-v0``'s, plus ``goal`` float32 (4,): the target's place (x, z mm) and the
    path's direction (x, z, unit) in the sensor's frame, from the arm's pose and the task's target (no touch
    needed). The oracle modes' ``true_pose_shear`` holds :data:`ORACLE_VARIABLES`.

    **Reward** per step: ``progress_mm / step_mm + 1 - min(deviation / 10 mm, 1) - 10 * 1[the episode ends early]``,
    ``progress`` the object's advance along the path, ``deviation`` its centre's distance from the path,
    ``step_mm`` the distance at ``speed_mm_s`` in a step.

    **Termination**: the object's centre within ``goal_tolerance_mm`` of the target or past it along the path
    (``"target"``, success: ``info["target_distance_mm"]`` says how close); more than 40 mm off the path
    (``"off_path"``), the dome 5 mm off the object (``"contact_lost"``), deeper than 4 mm (``"too_deep"``), an arm
    refusing a target (``"arm_limit"``). **Truncation**: ``max_episode_steps`` (800 = 80 s at 10 Hz).

    ``info`` adds ``shape``, ``object_world_mm`` (x, y, yaw deg), ``goal`` (as the observation's),
    ``target_distance_mm``, ``path_deviation_mm``, ``progress_mm``, ``slipping``, ``mass_kg``, ``table_friction``,
    ``contact_friction``.

    Args:
        shape: one of :data:`~simshear_gym.sim.pushing.PUSH_SHAPES` or ``"random"`` (one per reset).
        speed_mm_s: the pushing speed the reward counts progress against (and the servo controller keeps).
        path_length_mm, path_angle_deg: the target's distance and direction from the start (without
            ``randomise``).
        randomise: per reset, from its seed: mass 0.05-0.3 kg, table friction 0.2-0.5, skin friction 0.5-1.2,
            centre of pressure +-4 mm, the path 120-180 mm at +-25 deg, the contact +-4 mm off the face's middle,
            the face +-8 deg off square to the sensor.
        physics: the object's physics without ``randomise``.
        goal_tolerance_mm: how close to the target counts as reached.
        obs_mode, image_size_px, control_rate_hz, render_mode, reference_depth_mm, observation, history, ...:
            see :class:`~simshear_gym.envs.base.SimShearEnv` (``reference_depth_mm``: the start's depth).
        options of ``reset``: ``{"path_angle_deg": a, "path_length_mm": l, "contact_offset_mm": x}``.
    """

    servo_hints = ServoHints(law="push", process_std_mm=0.5)  # 0.5 mm: the object's unknown turn and slip per step

    def __init__(self, shape: str = "cube", obs_mode: str = "real", image_size_px: int = 128,
                 control_rate_hz: float = 10.0, render_mode: str | None = None, reference_depth_mm: float = 2.6,
                 speed_mm_s: float = 5.0, path_length_mm: float = 150.0, path_angle_deg: float = 0.0,
                 randomise: bool = False, physics: PushPhysicsConfig = PushPhysicsConfig(),
                 goal_tolerance_mm: float = 3.0, mount: HorizontalTacTipMount = HorizontalTacTipMount(),
                 termination: TerminationConfig = PUSH_TERMINATION, **base_kwargs) -> None:
        EzPickle.__init__(self, shape=shape, obs_mode=obs_mode, image_size_px=image_size_px,
                          control_rate_hz=control_rate_hz, render_mode=render_mode,
                          reference_depth_mm=reference_depth_mm, speed_mm_s=speed_mm_s,
                          path_length_mm=path_length_mm, path_angle_deg=path_angle_deg, randomise=randomise,
                          physics=physics, goal_tolerance_mm=goal_tolerance_mm, mount=mount,
                          termination=termination, **base_kwargs)
        if shape not in SHAPE_CHOICES:
            raise ValueError(f"unknown shape {shape!r}; expected one of {SHAPE_CHOICES}")
        if not isinstance(mount, HorizontalTacTipMount):
            raise ValueError(f"the pushing TacTip lies horizontally: mount must be a HorizontalTacTipMount, got "
                             f"{type(mount).__name__}")
        for name, value, low, high in (("speed_mm_s", speed_mm_s, 0.0, 10.0),
                                       ("path_length_mm", path_length_mm, 0.0, 200.0),
                                       ("path_angle_deg", path_angle_deg, -30.0, 30.0),
                                       ("goal_tolerance_mm", goal_tolerance_mm, 0.0, 20.0)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high
                    and (value > 0 or name == "path_angle_deg")):
                raise ValueError(f"{name} must be in ({low:g}, {high:g}], got {value!r}")
        if not isinstance(physics, PushPhysicsConfig):
            raise ValueError(f"physics must be a PushPhysicsConfig, got {type(physics).__name__}")
        self.shape_name = shape
        self.speed_mm_s = float(speed_mm_s)
        self.path_length_mm = float(path_length_mm)
        self.path_angle_deg = float(path_angle_deg)
        self.randomise = bool(randomise)
        self.physics = physics
        self.goal_tolerance_mm = float(goal_tolerance_mm)
        self.object: PushedObject | None = None
        self._bodies: dict[str, int] = {}
        self._target = np.zeros(2)
        self._path_direction = np.array([0.0, 1.0])
        self._path_length_mm = float(path_length_mm)
        self._progress_mm = self._reward_progress_mm = 0.0
        super().__init__(obs_mode=obs_mode, image_size_px=image_size_px, control_rate_hz=control_rate_hz,
                         render_mode=render_mode, reference_depth_mm=reference_depth_mm, mount=mount,
                         termination=termination, **base_kwargs)
        observations = dict(self.observation_space.spaces)
        observations["goal"] = goal_space()
        self.observation_space = spaces.Dict(observations)

    # ------------------------------------------------------------------ hooks
    def _build_scene(self) -> None:
        self.face_half_extents_mm = (math.inf, math.inf)
        self._use_shape(self.shape_name if self.shape_name != "random" else PUSH_SHAPES[0], self.physics)
        start = self._T_world_sensor_touching(0.0, 0.0, self.reference_depth_mm - SURFACE_DEPTH_MM)
        self._add_follower(FOLLOWER_T_WORLD_BASE, self.flange_pose_for_sensor(FOLLOWER_T_WORLD_BASE, start))

    def _use_shape(self, name: str, physics: PushPhysicsConfig, face_yaw_deg: float = 0.0) -> None:
        """The object of that shape at the start (yawed so its face 0 looks at the sensor, -y, then turned
        ``face_yaw_deg``), bodies made once."""
        shape = push_shape(name)
        pose = (START_WORLD_MM[0], START_WORLD_MM[1], math.radians(-90.0 + face_yaw_deg))
        self.object = PushedObject(shape, physics, self.tactip.config.dome_radius_mm, TABLE_Z_MM, pose)
        if name not in self._bodies:
            self._bodies[name] = spawn_push_object(self.world, shape, _PARKED)
        for other, body in self._bodies.items():
            placed = self.object.T_world_object() if other == name else _PARKED
            self.world.client.resetBasePositionAndOrientation(body, *pybullet_pose_fast(placed))

    def _T_world_sensor_touching(self, offset_mm: float, yaw_deg: float, penetration_mm: float) -> np.ndarray:
        """The sensor square to the world's +y (turned ``yaw_deg`` about the vertical), its axis through the point
        ``offset_mm`` along the pushed face from its middle, the dome ``penetration_mm`` into the face."""
        obj = self.object
        T_world_object = obj.T_world_object()
        normal = T_world_object[:3, 0]  # face 0's outward normal (object +x)
        along = T_world_object[:3, 1]
        half = obj.shape.half_width_mm()
        yaw = math.radians(yaw_deg)
        axis = np.array([math.sin(yaw), math.cos(yaw), 0.0])
        T = np.eye(4)
        T[:3, 2] = axis
        T[:3, 1] = [0.0, 0.0, -1.0]
        T[:3, 0] = np.cross(T[:3, 1], axis)
        if float(-axis @ normal) < 0.5:
            raise ValueError(f"the sensor must face the object: turned {yaw_deg} deg against its face")
        # the dome (a sphere of radius r behind the apex) on the line through the face's point offset_mm from its
        # middle, along the sensor's axis, where it sinks penetration_mm into the object
        r = obj.dome_radius_mm
        line = T_world_object[:3, 3] + offset_mm * along
        line[2] = TABLE_Z_MM + HEIGHT_MM / 2.0
        T_object_world = invert(T_world_object)

        def gap(t_mm: float) -> float:  # the sphere's signed clearance from the object at line - t axis
            centre = T_object_world @ np.r_[line - t_mm * axis, 1.0]
            return obj.shape.distance(centre[0], centre[1])[0] - (r - penetration_mm)

        near, far = 0.0, 4.0 * (half + r)  # inside (gap < 0) .. well outside
        for _ in range(60):
            mid = 0.5 * (near + far)
            near, far = (mid, far) if gap(mid) < 0.0 else (near, mid)
        T[:3, 3] = line - far * axis + r * axis
        return T

    def _reset_scene(self, rng: np.random.Generator, options: dict | None) -> None:
        options = dict(options or {})
        for key in ("path_angle_deg", "path_length_mm", "contact_offset_mm"):
            if key in options and not (isinstance(options[key], (int, float)) and math.isfinite(options[key])):
                raise ValueError(f"options[{key!r}] must be a finite number, got {options[key]!r}")
        shape = self.shape_name
        if shape == "random":
            shape = PUSH_SHAPES[int(rng.integers(len(PUSH_SHAPES)))]
        physics, angle, length, offset, face_yaw = self.physics, self.path_angle_deg, self.path_length_mm, 0.0, 0.0
        if self.randomise:
            physics = PushPhysicsConfig(
                mass_kg=float(rng.uniform(0.05, 0.3)), table_friction=float(rng.uniform(0.2, 0.5)),
                contact_friction=float(rng.uniform(0.5, 1.2)),
                centre_of_pressure_mm=tuple(float(v) for v in rng.uniform(-4.0, 4.0, 2)),
                normal_stiffness_n_per_mm=self.physics.normal_stiffness_n_per_mm,
                shear_stiffness_n_per_mm=self.physics.shear_stiffness_n_per_mm,
                max_substep_mm=self.physics.max_substep_mm)
            angle = float(rng.uniform(-25.0, 25.0))
            length = float(rng.uniform(120.0, 180.0))
            offset = float(rng.uniform(-4.0, 4.0))
            face_yaw = float(rng.uniform(-8.0, 8.0))
        angle = float(options.get("path_angle_deg", angle))
        length = float(options.get("path_length_mm", length))
        offset = float(options.get("contact_offset_mm", offset))
        if not (-30.0 <= angle <= 30.0 and 0.0 < length <= 200.0 and abs(offset) <= 10.0):
            raise ValueError(f"reset options out of range: path_angle_deg {angle} (|a| <= 30), path_length_mm "
                             f"{length} (0, 200], contact_offset_mm {offset} (|x| <= 10)")
        self._use_shape(shape, physics, face_yaw)
        start = self._T_world_sensor_touching(offset, 0.0, self.reference_depth_mm - SURFACE_DEPTH_MM)
        self.object.place(self.object.pose, start)
        self.follower.reset(self.flange_pose_for_sensor(FOLLOWER_T_WORLD_BASE, start))
        self.object.place(self.object.pose, self.follower.T_world_tool())
        heading = math.radians(angle)
        self._path_direction = np.array([math.sin(heading), math.cos(heading)])
        self._target = START_WORLD_MM + length * self._path_direction
        self._path_length_mm = length
        self._progress_mm = self._reward_progress_mm = 0.0

    def _command_scene(self, time_s: float, dt_s: float) -> None:
        pass  # nothing moves but the follower

    def _sync_scene(self) -> None:
        """The object yields to the dome's new pose; its body follows."""
        self.object.push(self.follower.T_world_tool())
        body = self._bodies[self.object.shape.name]
        self.world.client.resetBasePositionAndOrientation(body, *pybullet_pose_fast(self.object.T_world_object()))

    def _T_world_face(self) -> np.ndarray:
        return self._face_frame(self.follower.T_world_tool())

    def _face_frame(self, T_world_sensor: np.ndarray) -> np.ndarray:
        """The face under the dome now: origin at the contact point at the apex's height, z its outward normal
        (horizontal), y up."""
        obj = self.object
        T_world_object = obj.T_world_object()
        r = obj.dome_radius_mm
        centre = T_world_sensor[:3, 3] - r * T_world_sensor[:3, 2]
        local = invert(T_world_object) @ np.r_[centre, 1.0]
        d, nx, ny = obj.shape.distance(local[0], local[1])
        normal = T_world_object[:3, :3] @ np.array([nx, ny, 0.0])
        point = T_world_object[:3, :3] @ np.array([local[0] - d * nx, local[1] - d * ny, 0.0]) + T_world_object[:3, 3]
        T = np.eye(4)
        T[:3, 2] = normal
        T[:3, 1] = [0.0, 0.0, 1.0]
        T[:3, 0] = np.cross(T[:3, 1], normal)
        T[:3, 3] = [point[0], point[1], T_world_sensor[2, 3]]
        return T

    # --------------------------------------------------------- the contact
    def _measure(self) -> ContactState:
        T_world_sensor = self.follower.T_world_tool()
        T_world_face = self._face_frame(T_world_sensor)
        obj = self.object
        penetration = obj.penetration_mm(T_world_sensor)
        in_contact = obj.contact() is not None
        shear = obj.shear_sensor(T_world_sensor)
        pose_work = pose_from_matrix_fast(self.T_work_face @ invert(T_world_face) @ T_world_sensor)
        self._progress_mm, deviation = self._along_and_off_path_mm()
        return ContactState(pose_work, float(penetration), True, in_contact, shear, deviation,
                            self._face_yaw_deg(pose_work), T_world_sensor)

    @staticmethod
    def _face_yaw_deg(pose_work: np.ndarray) -> float:
        """The face's turn against the sensor about the vertical: the label pose's Ry (sensor y is down)."""
        return float(pose_work[4])

    def _bearing_deg(self, T_world_sensor: np.ndarray) -> float:
        """The path's direction from the sensor's axis about the vertical, + towards sensor +x."""
        axis, side = T_world_sensor[:2, 2], T_world_sensor[:2, 0]
        return math.degrees(math.atan2(float(self._path_direction @ side), float(self._path_direction @ axis)))

    def _oracle_variables(self, state: ContactState) -> np.ndarray:
        values = np.array([state.depth_mm, state.shear_sensor[0], state.rz_error_deg,
                           self._bearing_deg(state.T_world_sensor)])
        return np.clip(values, -TRUE_POSE_SHEAR_LIMIT, TRUE_POSE_SHEAR_LIMIT).astype(np.float32)

    def _observation(self, state: ContactState, move: np.ndarray | None) -> dict[str, np.ndarray]:
        obs = super()._observation(state, move)
        obs["goal"] = self.goal_in_sensor(state.T_world_sensor)
        return obs

    def goal_in_sensor(self, T_world_sensor: np.ndarray) -> np.ndarray:
        """float32 (4,): the target (x, z mm) and the path's direction (x, z) in the sensor frame."""
        return push_goal(T_world_sensor[:2, 3], T_world_sensor[:2, 0], T_world_sensor[:2, 2], self._target,
                         self._path_direction)

    def target_distance_mm(self) -> float:
        return float(np.linalg.norm(np.asarray(self.object.pose[:2]) - self._target))

    def _termination(self, state: ContactState, arm_error: str) -> str:
        config = self.termination_config
        if arm_error:
            return "arm_limit"
        remaining = self.path_length_now_mm() - self._progress_mm
        if self.target_distance_mm() <= self.goal_tolerance_mm or remaining <= 0.0:
            return "target"
        if state.contact_error_mm > config.max_contact_error_mm:
            return "off_path"
        if state.penetration_mm < -config.lost_contact_mm:
            return "contact_lost"
        if state.penetration_mm > config.max_penetration_mm:
            return "too_deep"
        return ""

    def path_length_now_mm(self) -> float:
        """This episode's path length (start to target), mm."""
        return self._path_length_mm

    def _reward(self, state: ContactState, termination: str = "") -> float:
        step_mm = self.speed_mm_s * self.dt_s
        progress = (self._progress_mm - self._reward_progress_mm) / step_mm
        self._reward_progress_mm = self._progress_mm
        early = bool(termination) and termination != "target"
        return (progress + 1.0 - min(state.contact_error_mm / 10.0, 1.0)
                - self.reward_config.termination_penalty * early)

    def _target_world_mm(self) -> np.ndarray:
        return np.array([self._target[0], self._target[1], TABLE_Z_MM + HEIGHT_MM / 2.0])

    def _scene_target_world_mm(self) -> np.ndarray:
        return np.array([*self.object.pose[:2], TABLE_Z_MM])

    def _task_info(self) -> dict:
        obj = self.object
        return {"shape": obj.shape.name, "object_world_mm": np.array([*obj.pose[:2], math.degrees(obj.pose[2])]),
                "goal": self.goal_in_sensor(self.follower.T_world_tool()),
                "target_distance_mm": self.target_distance_mm(), "path_deviation_mm": self._along_and_off_path_mm()[1],
                "progress_mm": self._progress_mm, "slipping": obj.slipping, "mass_kg": obj.config.mass_kg,
                "table_friction": obj.config.table_friction, "contact_friction": obj.config.contact_friction}

    def _along_and_off_path_mm(self) -> tuple[float, float]:
        """The object's centre: how far along the path from the start, and how far off it (mm)."""
        offset = np.asarray(self.object.pose[:2]) - START_WORLD_MM
        direction = self._path_direction
        return float(offset @ direction), abs(float(offset[0] * direction[1] - offset[1] * direction[0]))


_PARKED = np.eye(4)
_PARKED[2, 3] = -5000.0  # out of every camera's sight


def make_push_vector_env(num_envs: int = 1, max_episode_steps: int | None = 800, workers: int | None = None,
                         translate_in: str = "workers", start_method: str | None = None, **env_kwargs):
    """The ``vector_entry_point`` of ``SimShearPush-v0``: a :class:`~simshear_gym.envs.vector.SimShearVectorEnv`
    of pushing sub-envs (batched translation; the ``goal`` stacked like every key)."""
    from simshear_gym.envs.vector import SimShearVectorEnv

    return SimShearVectorEnv("simshear_gym.envs.push:SimShearPushEnv", num_envs, env_kwargs, max_episode_steps,
                             workers, translate_in, start_method)


__all__ = ["FOLLOWER_T_WORLD_BASE", "ORACLE_VARIABLES", "PUSH_TERMINATION", "SHAPE_CHOICES", "START_WORLD_MM",
           "SimShearPushEnv", "TABLE_Z_MM", "make_push_vector_env"]
