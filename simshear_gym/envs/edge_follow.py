"""``SimShearEdgeFollow-v0``: slide a TacTip round the edge of a flat object, centred on the edge at a set depth."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from gymnasium.utils import EzPickle

from simshear_gym.contract import TRUE_POSE_SHEAR_LIMIT, ServoHints
from simshear_gym.data.labels import wrap_deg
from simshear_gym.envs.base import ContactState, SimShearEnv, pybullet_pose_fast
from simshear_gym.envs.tracking import FOLLOWER_T_WORLD_BASE
from simshear_gym.sim.contours import OUTLINES, Contour, ContourObject, edge_contact, spawn_contour_object
from simshear_gym.sim.replay import ReplayGeometry
from simshear_gym.sim.shear import ShearTrackerConfig
from simshear_gym.transforms import invert, pose_from_matrix_fast, pose_to_matrix

OUTLINE_CHOICES: tuple[str, ...] = OUTLINES + ("random",)
SIZES_MM: tuple[float, ...] = (32.0, 40.0, 48.0)
"""The objects' nominal radii (half sides): 40 mm, or one of the three drawn per reset with ``randomise``."""
# The object lies where the tracking plate starts: its centre 310 mm out from the follower's base, its top face
# 60 mm below the arms' J2 axes, so every outline point (up to 48 x 1.18 mm from the centre) is in the MG400's reach.
T_WORLD_OBJECT = pose_to_matrix(np.array([380.0, 0.0, -60.0, 0.0, 0.0, 0.0]))
EDGE_GEOMETRY = ReplayGeometry()
"""Where the edge lies in the labels' work frame (the edge data's): y of the edge line, material at +y."""
EDGE_SHEAR = ShearTrackerConfig(slip_limit_mm=3.0)
"""Sliding along the edge drags the skin to its slip limit: 3 mm keeps the shear inside the real shear data's
range (|move x, y| <= 5 mm), where the translator and the GDNN learned it."""
ORACLE_VARIABLES: tuple[str, ...] = ("edge_offset_mm", "z_mm", "shear_along_edge_mm", "edge_angle_deg")
"""``true_pose_shear`` of the oracle modes, in order (the angle last: the observation's bounds are 50, 50, 50,
180)."""


class SimShearEdgeFollowEnv(SimShearEnv):
    """Slide a downward TacTip once round the edge of a flat object, keeping the dome's apex over the edge at the
    reference depth (Tactile Gym's edge following, with shear).

    A flat object (:mod:`simshear_gym.sim.contours`: ``disk``, ``rounded_square``, ``clover`` or ``wavy``
    outline, 40 mm radius or half side, 20 mm thick) lies still in front of the follower MG400, whose TacTip
    (pointing down, as in ``SimShearTracking-v0``) starts on the edge at the reference depth. The images are those
    of the labels' edge data: the shipped edge shPix2pix translates them (``obs_mode="real"``), and the shipped
    edge GDNN reads the offset across the edge (``y_mm``), the depth and the edge's angle in the sensor frame from
    them. The shear is the skin's drag while sliding (slip limit :data:`EDGE_SHEAR`). The sensor need not turn: the
    MG400's J4 turns less than a lap, so the angle it reads is how it finds the way along the edge.

    **Action**: as ``SimShearTracking-v0``'s (dx, dy, dz mm, dRz deg in the sensor frame, per step, [-1, 1] of
    1 mm, 1 mm, 1 mm, 2 deg).

    **Observation**: as ``SimShearTracking-v0``'s (``observation``, ``history``); the oracle modes'
    ``true_pose_shear`` holds :data:`ORACLE_VARIABLES`: the signed offset of the apex from the edge (mm, + over the
    material), the depth (labels' z, mm), the shear along the edge (mm) and the edge angle (the labels' Rz, deg).

    **Reward** per step: ``progress_mm / step_mm + 1 - min(|offset| / 2 mm, 1) - min(|depth error| / 1 mm, 1)
    - 10 * 1[the episode ends early]``, ``step_mm`` the distance covered at ``speed_mm_s`` in a step: about 2
    per step while following at speed, centred and at depth.

    **Termination**: a full lap round the edge (``"lap"``, a success: no penalty); the apex more than
    ``max_offset_mm`` (6 mm: the edge data's range) from the edge (``"edge_lost"``), lifted 1 mm off the top face
    (``"contact_lost"``), deeper than 5 mm (``"too_deep"``), or an arm refusing a target (``"arm_limit"``).
    **Truncation**: ``max_episode_steps`` of the registration (1000 steps = 100 s at 10 Hz; a lap at 5 mm/s takes
    37-75 s).

    ``info`` as the tracking env's (``contact_error_mm`` is the apex's distance from the edge), plus ``outline``,
    ``edge_offset_mm``, ``edge_angle_deg``, ``progress_mm`` (along the edge, clockwise seen from above, since
    reset), ``perimeter_mm``, ``edge_point_world_mm`` (the nearest edge point).

    Args:
        outline: one of :data:`~simshear_gym.sim.contours.OUTLINES`, or ``"random"`` (one drawn per reset).
        speed_mm_s: the following speed the reward counts progress against (and the servo controller keeps).
        randomise: per reset, draw the size (one of :data:`SIZES_MM`), the start point along the edge, the start
            offset (+-2 mm) and the sensor's turn about its axis (+-180 deg) from the reset's seed.
        max_offset_mm: how far from the edge the apex may stray.
        obs_mode, image_size_px, control_rate_hz, render_mode, reference_depth_mm, observation, history, ...:
            see :class:`~simshear_gym.envs.base.SimShearEnv`.
        options of ``reset``: ``{"start_arc_mm": s, "start_offset_mm": y, "start_angle_deg": a}``.
    """

    translator_contact = "edge"
    servo_hints = ServoHints(law="edge", posenet="edge")

    def __init__(self, outline: str = "disk", obs_mode: str = "real", image_size_px: int = 128,
                 control_rate_hz: float = 10.0, render_mode: str | None = None, reference_depth_mm: float = 4.0,
                 speed_mm_s: float = 5.0, randomise: bool = False, max_offset_mm: float = 6.0,
                 shear_config: ShearTrackerConfig = EDGE_SHEAR, **base_kwargs) -> None:
        EzPickle.__init__(self, outline=outline, obs_mode=obs_mode, image_size_px=image_size_px,
                          control_rate_hz=control_rate_hz, render_mode=render_mode,
                          reference_depth_mm=reference_depth_mm, speed_mm_s=speed_mm_s, randomise=randomise,
                          max_offset_mm=max_offset_mm, shear_config=shear_config, **base_kwargs)
        if outline not in OUTLINE_CHOICES:
            raise ValueError(f"unknown outline {outline!r}; expected one of {OUTLINE_CHOICES}")
        for name, value, low, high in (("speed_mm_s", speed_mm_s, 0.0, 20.0), ("max_offset_mm", max_offset_mm, 0.0,
                                                                               8.0)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and low < value <= high):
                raise ValueError(f"{name} must be in ({low:g}, {high:g}], got {value!r}")
        self.outline_name = outline
        self.speed_mm_s = float(speed_mm_s)
        self.randomise = bool(randomise)
        self.max_offset_mm = float(max_offset_mm)
        self.contour: Contour | None = None
        self._contours: dict[tuple[str, float], tuple[Contour, int]] = {}
        self._T_object_world = invert(T_WORLD_OBJECT)
        self._T_work_edge = EDGE_GEOMETRY.T_work_stimulus()
        self._T_edge_work = invert(self._T_work_edge)
        self._progress_mm = self._reward_progress_mm = 0.0
        self._arc_mm: float | None = None
        self._edge: tuple[float, np.ndarray, float, float] = (0.0, np.zeros(3), 0.0, 0.0)
        super().__init__(obs_mode=obs_mode, image_size_px=image_size_px, control_rate_hz=control_rate_hz,
                         render_mode=render_mode, reference_depth_mm=reference_depth_mm, shear_config=shear_config,
                         **base_kwargs)
        # The edge frame's unknown drift per step (curvature), mm, for the controllers made for this env. Set after
        # the base's constructor, which builds the estimate observation's estimator: that one keeps the
        # estimator's default process noise (what the shipped edge policy was trained on).
        self.servo_hints = replace(self.servo_hints, process_std_mm=0.3)

    # ------------------------------------------------------------------ hooks
    def _build_scene(self) -> None:
        self.face_half_extents_mm = (math.inf, self.max_offset_mm)
        self._use_contour(self.outline_name if self.outline_name != "random" else OUTLINES[0], 40.0)
        start = self.T_world_sensor_on_edge(0.0, 0.0, self.reference_depth_mm, 0.0)
        self._add_follower(FOLLOWER_T_WORLD_BASE, self.flange_pose_for_sensor(FOLLOWER_T_WORLD_BASE, start))

    def _use_contour(self, outline: str, size_mm: float) -> None:
        """Make the object of that outline and size the one in the scene (bodies are made once, then parked)."""
        key = (outline, float(size_mm))
        if key not in self._contours:
            contour = Contour(ContourObject(outline, size_mm))
            self._contours[key] = (contour, spawn_contour_object(self.world, contour, _PARKED))
        for other, (_, body) in self._contours.items():
            placed = T_WORLD_OBJECT if other == key else _PARKED
            self.world.client.resetBasePositionAndOrientation(body, *pybullet_pose_fast(placed))
        self.contour = self._contours[key][0]

    def T_world_sensor_on_edge(self, arc_mm: float, offset_mm: float, depth_mm: float,
                               angle_deg: float) -> np.ndarray:
        """The sensor pose at an edge label pose (offset across the edge, + over the material; depth; edge angle)
        at the edge point ``arc_mm`` along the outline (counter-clockwise from its first point)."""
        point, tangent = self.contour.point_at(arc_mm)
        T_world_edge = T_WORLD_OBJECT @ self.contour.T_object_edge(point, tangent)
        label = np.array([0.0, EDGE_GEOMETRY.edge_y_mm + offset_mm, depth_mm, 0.0, 0.0, angle_deg])
        return T_world_edge @ self._T_edge_work @ pose_to_matrix(label)

    def _reset_scene(self, rng: np.random.Generator, options: dict | None) -> None:
        options = dict(options or {})
        outline = self.outline_name
        if outline == "random":
            outline = OUTLINES[int(rng.integers(len(OUTLINES)))]
        size = SIZES_MM[int(rng.integers(len(SIZES_MM)))] if self.randomise else 40.0
        self._use_contour(outline, size)
        arc, offset, angle = 0.0, 0.0, 0.0
        if self.randomise:
            arc = float(rng.uniform(0.0, self.contour.perimeter_mm))
            offset = float(rng.uniform(-2.0, 2.0))
            angle = float(rng.uniform(-180.0, 180.0))
        for key in ("start_arc_mm", "start_offset_mm", "start_angle_deg"):
            if key in options and not (isinstance(options[key], (int, float)) and math.isfinite(options[key])):
                raise ValueError(f"options[{key!r}] must be a finite number, got {options[key]!r}")
        arc = float(options.get("start_arc_mm", arc))
        offset = float(options.get("start_offset_mm", offset))
        angle = float(options.get("start_angle_deg", angle))
        if abs(offset) > min(3.0, self.max_offset_mm):
            raise ValueError(f"options['start_offset_mm'] must be within +-{min(3.0, self.max_offset_mm):g} mm of "
                             f"the edge, got {offset}")
        self._progress_mm, self._reward_progress_mm, self._arc_mm = 0.0, 0.0, None
        T_world_sensor = self.T_world_sensor_on_edge(arc, offset, self.reference_depth_mm, angle)
        self.follower.reset(self.flange_pose_for_sensor(FOLLOWER_T_WORLD_BASE, T_world_sensor))

    def _command_scene(self, time_s: float, dt_s: float) -> None:
        pass  # the object lies still

    def _sync_scene(self) -> None:
        pass

    def _T_world_face(self) -> np.ndarray:
        return T_WORLD_OBJECT

    # --------------------------------------------------------- the edge
    def _measure(self) -> ContactState:
        T_world_sensor = self.follower.T_world_tool()
        T_object_sensor = self._T_object_world @ T_world_sensor
        edge = edge_contact(self.contour, T_object_sensor, self._T_work_edge, EDGE_GEOMETRY.edge_y_mm)
        in_contact = edge.touches(self.tactip.config.dome_radius_mm)
        shear = self.shear_tracker.update(pose_from_matrix_fast(self.T_work_face @ T_object_sensor), in_contact)
        if self._arc_mm is not None:  # clockwise (decreasing ccw arc) is forward
            half = self.contour.perimeter_mm / 2.0
            self._progress_mm += (self._arc_mm - edge.arc_mm + half) % self.contour.perimeter_mm - half
        self._arc_mm = edge.arc_mm
        angle = float(wrap_deg(edge.label_pose[5]))
        along_mm = float(np.cos(np.radians(angle)) * shear[0] - np.sin(np.radians(angle)) * shear[1])
        point_world = T_WORLD_OBJECT[:3, :3] @ np.r_[edge.point_mm, 0.0] + T_WORLD_OBJECT[:3, 3]
        self._edge = (edge.offset_mm, point_world, angle, along_mm)
        return ContactState(edge.label_pose, edge.penetration_mm, abs(edge.offset_mm) <= self.max_offset_mm,
                            in_contact, shear, abs(edge.offset_mm), angle, T_world_sensor)

    def _oracle_variables(self, state: ContactState) -> np.ndarray:
        offset, _, angle, along = self._edge
        values = np.array([offset, state.depth_mm, along, angle])
        return np.clip(values, -TRUE_POSE_SHEAR_LIMIT, TRUE_POSE_SHEAR_LIMIT).astype(np.float32)

    def _termination(self, state: ContactState, arm_error: str) -> str:
        config = self.termination_config
        if arm_error:
            return "arm_limit"
        if not state.on_face:
            return "edge_lost"
        if state.penetration_mm < -config.lost_contact_mm or not state.in_contact:
            return "contact_lost"
        if state.penetration_mm > config.max_penetration_mm:
            return "too_deep"
        if self._progress_mm >= self.contour.perimeter_mm:
            return "lap"
        return ""

    def _reward(self, state: ContactState, termination: str = "") -> float:
        step_mm = self.speed_mm_s * self.dt_s
        progress = (self._progress_mm - self._reward_progress_mm) / step_mm
        self._reward_progress_mm = self._progress_mm
        depth_error = abs(state.depth_mm - self.reference_depth_mm)
        early = bool(termination) and termination != "lap"
        return (progress + 1.0 - min(state.contact_error_mm / 2.0, 1.0) - min(depth_error, 1.0)
                - self.reward_config.termination_penalty * early)

    def _target_world_mm(self) -> np.ndarray:
        return self._edge[1].copy()

    def _scene_target_world_mm(self) -> np.ndarray:
        return T_WORLD_OBJECT[:3, 3]

    def _task_info(self) -> dict:
        offset, point, angle, along = self._edge
        return {"outline": self.contour.spec.outline, "edge_offset_mm": offset, "edge_angle_deg": angle,
                "shear_along_edge_mm": along, "progress_mm": self._progress_mm,
                "perimeter_mm": self.contour.perimeter_mm, "edge_point_world_mm": point.copy()}


_PARKED = pose_to_matrix(np.array([0.0, 0.0, -5000.0, 0.0, 0.0, 0.0]))  # out of every camera's sight


def make_edge_follow_vector_env(num_envs: int = 1, max_episode_steps: int | None = 1000, workers: int | None = None,
                                translate_in: str = "workers", start_method: str | None = None, **env_kwargs):
    """The ``vector_entry_point`` of ``SimShearEdgeFollow-v0``: a
    :class:`~simshear_gym.envs.vector.SimShearVectorEnv` of edge-following sub-envs (batched translation)."""
    from simshear_gym.envs.vector import SimShearVectorEnv

    return SimShearVectorEnv("simshear_gym.envs.edge_follow:SimShearEdgeFollowEnv", num_envs, env_kwargs,
                             max_episode_steps, workers, translate_in, start_method)


__all__ = ["EDGE_GEOMETRY", "EDGE_SHEAR", "ORACLE_VARIABLES", "OUTLINE_CHOICES", "SimShearEdgeFollowEnv",
           "T_WORLD_OBJECT", "make_edge_follow_vector_env"]
