"""``SimShearCoLift-v0``: carry an object together with a leader arm, holding it against the leader's plate with a
horizontal TacTip, by friction alone."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from gymnasium.utils import EzPickle

from simshear_gym.contract import TRUE_POSE_SHEAR_LIMIT, HorizontalTacTipMount, ServoHints
from simshear_gym.envs.base import (
    ContactState,
    SimShearEnv,
    TerminationConfig,
    pybullet_pose_fast,
)
from simshear_gym.envs.trajectories import (
    COLIFT_TRAJECTORIES,
    Trajectory,
    TrajectoryConfig,
)
from simshear_gym.sim.colift_scene import FIRM_TIP, CoLiftScene, CoLiftSceneConfig, translation_matrix, upright_plate
from simshear_gym.sim.mg400_arm import SimMG400
from simshear_gym.sim.objects import OBJECTS, PAYLOADS, spawn_object
from simshear_gym.sim.replay import SURFACE_DEPTH_MM
from simshear_gym.sim.tactip import TacTipConfig
from simshear_gym.transforms import invert, pose_to_matrix, rz_matrix

OBJECT_NAMES: tuple[str, ...] = tuple(OBJECTS)  # prism, egg, brain, ducky
TRAJECTORY_CHOICES: tuple[str, ...] = COLIFT_TRAJECTORIES + ("random",)
__all__ = ["COLIFT_TRAJECTORIES", "OBJECT_NAMES", "HorizontalTacTipMount", "SimShearCoLiftEnv",
           "make_colift_vector_env"]

# Scene layout, world frame (mm): z up, z = 0 at both arms' J2 axes. The grip axis is world x at the start.
LEADER_T_WORLD_BASE = np.eye(4)
LEADER_START_POSE_MM_DEG = np.array([280.0, 0.0, 0.0, 0.0])  # leader flange, its base frame
# The plate on the leader's flange: upright, its face 50 mm beyond and 60 mm below the flange, facing the
# follower (plate +z = world +x at the start, plate +y up): see colift_scene.upright_plate.
T_FLANGE_PLATE = upright_plate(np.array([50.0, 0.0, -60.0]), yaw_deg=-90.0)
# The follower faces the leader 750 mm away: with the plate face at x = 330 mm, an object 30-42 mm thick and the
# TacTip 95 mm long, its flange starts 286-298 mm out, mid-way in the MG400's reach.
FOLLOWER_T_WORLD_BASE = pose_to_matrix(np.array([750.0, 0.0, 0.0, 0.0, 0.0, 180.0]))
ROTATION_LIMIT_DEG = 10.0  # largest amplitude of the leader's optional turn about the vertical (reach-checked)
START_OFFSET_LIMIT_MM = 40.0
# Co-lift ends on a drop. Beyond that: the follower 50 mm off its target (farther than any object's size: it has
# lost the object), or the object 10 mm into the 20 mm dome (physical depth; 3 mm at the start). lost_contact_mm
# is unused: losing the grip is a drop.
COLIFT_TERMINATION = TerminationConfig(max_contact_error_mm=50.0, max_penetration_mm=10.0)
SQUEEZE_MM = {"light": 3.0, "heavy": 4.0}  # the default squeeze per payload (reference depth - face depth)
_PHYSICS_RATE_HZ = 240.0  # nominal; the env picks substeps so that a control period is a whole number of them
_T_SENSOR_TURN = np.diag([1.0, -1.0, -1.0, 1.0])  # the scene's plate -> sensor turn (180 deg about x)


def heading_deg(axis_world: np.ndarray) -> float:
    """Direction of a (horizontal) axis about the vertical: atan2(y, x), deg."""
    return math.degrees(math.atan2(axis_world[1], axis_world[0]))


class SimShearCoLiftEnv(SimShearEnv):
    """Carry an object with a leader MG400, squeezing it against the leader's plate with a horizontal TacTip.

    Two MG400s face each other 750 mm apart. The **leader** holds an upright 60 x 60 mm plate on a bracket (face
    50 mm beyond and 60 mm below its flange, facing the follower) and moves it along ``trajectory`` (see
    :mod:`simshear_gym.envs.trajectories`: ``circular_wave``, a horizontal circle with vertical waves, moving the
    object along and across the grip axis; ``star``, a star outline in the vertical plane of the plate, lifting
    it; like the paper's, both are translations: ``rotation_deg`` adds a turn of the plate about the vertical).
    The **follower** carries the TacTip lying horizontally (:class:`HorizontalTacTipMount`: axis along its
    flange's x, 60 mm below it, apex 95 mm ahead) and squeezes the object (``object_name``: ``prism`` 30 x 40 x
    30 mm box, rigid ``egg``, soft ``brain`` ellipsoid, ``ducky``; 30 g unless ``mass_kg``) against the plate.
    Nothing but friction holds the object: if the grip loosens or the follower lags, it slips and falls. The
    task: keep the squeeze (the reference depth) and the sensor's place relative to the plate (variables: depth z,
    shear x, shear y, yaw). Holding still does not work: the leader carries the object away from the tip, or drags
    it across the dome until it falls.

    **Physics** (:class:`~simshear_gym.sim.colift_scene.CoLiftScene`, its own PyBullet world, rebuilt at each
    reset): the object is a free body; the plate and the tip (a sphere of the dome's radius) are heavy bodies
    driven by velocity to the arms' tool poses (``_sync_scene`` bridges the kinematic arms to them: each step
    the scene moves plate and tip from the previous to the new ``T_world_tool`` of the leader and follower over
    ``substeps`` physics steps at about 240 Hz, 24 at 10 Hz). The tip's contact is soft (500 N/m, 5 N s/m:
    about a real TacTip's few newtons over a few millimetres), so the 3 mm squeeze is the dome's deformation and
    presses the object with about 1.5 N; the plate's contact is rigid; the soft brain adds its own compliance.
    The skin is compliant across the optical axis too (a 100 N/m spring between the sensor and the tip body,
    plus rolling and spinning friction for the contact patch, and friction anchors so contacts under load do not
    creep), so when the follower lags, the skin shears over the object, which stays on the plate, and the image
    shows the lag as shear.
    The tactile **image** is not the physics contact: it is the TacTip's render of the object's penetration
    into the *undeformed* dome at the follower's TCP (a visual copy of the object in the env's own world, moved
    to the physics object's pose each step); with a soft contact that overlap is the deformation.

    Both arms are kinematic :class:`~simshear_gym.sim.mg400_arm.SimMG400` in servo mode: each step sends one
    ServoP to each, reached within the control period, and every pose is checked against the MG400's limits.

    **Action** ``Box(-1, 1, (4,), float32)``: a relative move of the sensor per step:

    ======  ==============================================  ======  ====================================
    index   meaning                                         unit    full scale (``ActionScale`` default)
    ======  ==============================================  ======  ====================================
    0       dx, sensor x (horizontal, across the grip)      mm      1 mm per step
    1       dy, sensor y (down)                             mm      1 mm per step
    2       dz, sensor z (+: into the object, squeezing)    mm      1 mm per step
    3       dRz: turn about the **vertical** through the    deg     2 deg per step
            dome apex (+: anticlockwise seen from above)
    ======  ==============================================  ======  ====================================

    The MG400's flange is always level, so the only rotation it can give a horizontal sensor is about the
    vertical (a yaw of the grip axis); index 3 is that, not a roll about the sensor axis. NaN, wrong shape or
    values outside [-1, 1] raise ``ValueError``.

    **Observation** ``Dict``, by ``observation`` as in ``SimShearTracking-v0`` (k = ``history``):

    ===================  ==========================  ============================================================
    key                  space                       meaning
    ===================  ==========================  ============================================================
    ``tactile``          Box uint8 (k, S, S)         "tactile" (default), "tactile+estimate": the last k TacTip
                                                     images, S = ``image_size_px`` (128 or 64); shPix2pix
                                                     translated ("real", "oracle_real"; the shipped "surface"
                                                     translator) or raw depth ("sim", "oracle"; 255 = 14.5 mm)
    ``tcp_pose``         Box float32 (4,)            "tactile" only: follower TCP (dome apex) x, y, z mm and
                                                     flange R deg, in the follower's base frame (as ``GetPose``
                                                     with the tool set)
    ``estimate``         Box float32 (16 k,)         "estimate", "tactile+estimate": per image, the servo
                                                     controller's estimator on it (the shipped ``colift`` GDNN,
                                                     process noise 1.5 mm; ``estimator=``), normalised relative
                                                     to the reference depth as in ``SimShearTracking-v0``
    ``last_action``      Box float32 (4,) in         "estimate+action" only (with ``estimate``): the move
                         [-1, 1]                     commanded since the previous image over the full scale
    ``true_pose_shear``  Box float32 (4,)            oracle modes only: depth (label convention: the object's
                                                     face, where it sat on the plate at reset and carried with
                                                     the plate, at 2.2 mm), shear x, y (mm, sensor frame: the
                                                     sensor's slide since reset over that face, stick-slip limited
                                                     at 7.5 mm), yaw (deg, the sensor's turn about the vertical
                                                     from its target, like action 3)
    ===================  ==========================  ============================================================

    Why the oracle's shear is taken over the face *as carried by the plate* while ``info["shear_sensor_mm_deg"]``
    (which also conditions the translator) is the skin's deflection: the contact error is relative to the plate,
    so the oracle holds the grip where the plate says. The skin shears instead of moving the object (see the
    physics above), so the two agree to within the object's creep on the plate (< 0.5 mm in the scene's tests).

    **Reward** (``RewardConfig``) ``1 - min(e / 5 mm, 1) + exp(-(e / 1 mm)^2) - 1[tip not touching the object]
    - 10 * 1[the step ends the episode]`` with ``e`` the contact error: in [0, 2] while the tip touches the
    object; a drop ends the episode, costing 10 and the rest of the reward.

    **Contact error** ``info["contact_error_mm"]`` every step: the distance between the follower's TCP and its
    target point, where the TCP was at reset relative to the plate, carried along with the (commanded) plate.
    ``info`` also holds ``sensor_world_mm`` and ``target_world_mm`` (3,: the two points, world frame), ``dropped``,
    ``yaw_error_deg``, ``contact_depth_mm`` (the object's physical penetration into the dome), ``object_slip_mm``
    (the object's drift relative to the plate), ``in_contact`` (the tip touches the object), ``penetration_mm`` and
    ``depth_mm`` (relative to the object's face as carried by the plate), ``shear_sensor_mm_deg`` (6,),
    ``time_s``, ``steps_out_of_contact``, ``termination`` (reason or ``""``), ``trajectory``, ``object_name`` and,
    when an arm refused a target, ``arm_error``.

    **Termination** (``termination``, default ``COLIFT_TERMINATION``), in this order: an arm refuses a target
    outside its limits (``"arm_limit"``; the step returns normally); the object falls (slips > 20 mm from its place
    on the plate, or touches neither plate nor tip: ``"dropped"``; losing the grip always ends so, there is no
    separate contact loss); contact error > 50 mm (``"contact_error"``); the object > 10 mm into the dome, its
    physical depth (``"too_deep"``: a box's edge dug in when the follower does not turn with the plate).
    **Truncation**: ``max_episode_steps`` of the registration (500 steps = 50 s at 10 Hz; both default
    trajectories end within 38 s, after which the plate holds still).

    **Render modes** (``render_mode``): ``"rgb_array"``: ``render()`` returns uint8 (180, 420, 3), the scene (arms,
    TacTip, the plate and the object) beside the newest tactile image; ``"human"``: that frame in a window,
    refreshed on every ``reset`` and ``step`` at the control rate (needs a display: ``xvfb-run`` on a machine
    without one); None (default): no scene bodies, the fastest steps.

    Args:
        trajectory: ``circular_wave``, ``star`` or ``random`` (one drawn per reset).
        object_name: one of :data:`OBJECT_NAMES`.
        mass_kg: the object's mass (None: the payload's: 30 g light; heavy: prism 2.0, egg 1.5, ducky 1.0, brain
            0.5 kg); a light object heavier than ~0.3 kg slips out of the soft grip.
        payload: ``"light"`` (the paper's objects on the soft TacTip) or ``"heavy"``
            (:data:`~simshear_gym.sim.objects.HEAVY_OBJECTS` on the firm TacTip of
            :data:`~simshear_gym.sim.colift_scene.FIRM_TIP`, squeezed 4 mm, against a rubber-padded plate): the
            skin carries a share of the load, so the weight shows as a steady downward shear from the first image
            on (0.6-2.1 mm), while the plate's moves drag the object and show on the skin as for a light one; a
            follower that keeps the load's shear, holding its place, carries the object; one that servoes it to
            zero walks the skin down and the object slides (``ServoController``'s ``hold_load``). The env asks the
            servo for 0.4 mm more shear along the weight than the grasp's (``servo_hints.load_margin_mm``) and
            deadbeat shear gains (``servo_hints.shear_gains`` kp 1, ki 0.5): a follower that carries only what it
            felt at the grasp, and answers the plate's turns over several steps, lets the duck and the soft ball
            slide.
        obs_mode, image_size_px, control_rate_hz, render_mode, observation, history, estimator: see
            :class:`~simshear_gym.envs.base.SimShearEnv` (defaults ``"real"``, 128, 10 Hz, None, ``"tactile"``, 1).
        reference_depth_mm: the depth to keep (label convention); None: the payload's squeeze, 5.2 mm = a 3 mm
            squeeze (light), 6.2 mm = 4 mm (heavy).
        speed_mm_s: the leader's speed along its path.
        rotation_deg: amplitude of the plate's turn about the vertical along the path (``rotation_deg *
            sin(2 pi s)``, s the fraction travelled; within +-10 deg); 0 (default): the paper's translations.
            A turn is not observable by touch on a round object: the egg, brain and duck roll on the rigid plate
            as it turns under them (the object keeps its orientation to the skin, whose contact patch holds it),
            so the follower sees no shear while the plate carries its target away (a 10 deg turn rolls the egg
            3.7 mm, ``tests/test_colift_scene.py``); only the prism's flat face turns with the plate.
        randomise: per reset, draw the trajectory's scale (x0.7-1.3), speed (x0.7-1.3), turn (-1..1 x
            ``rotation_deg``) and the leader's start place (+-10 mm in world x, y, z) from the reset's seed.
        options of ``reset``: ``{"start_offset_mm": (x, y, z)}`` sets the leader's start place (world mm, within
            +-40 mm).
        Other keyword arguments (``action_scale``, ``reward``, ``termination``, ``arm_config``, ``mount``, ...) go
        to the base; ``mount`` must be a :class:`HorizontalTacTipMount`.

    Version history: v0 (initial; before the first release: the skin's shear compliance and friction anchors,
    so a lag shears the skin instead of moving the object, and no turn of the plate unless ``rotation_deg``; the
    ``observation`` / ``history`` arguments and the reward of ``SimShearTracking-v0``'s version history).
    """

    # The shipped GDNN trained on this env's own images (simshear collect-env; "colift_heavy" for payload="heavy")
    # and the servo estimator's process noise (mm per step): the plate moves up to 6.5 mm/s (randomised speed) and
    # the star reverses at its corners, so the filter must let a reading move the state by more than the
    # tracking default of 0.4 mm (with 0.4 the state lagged a star corner until the skin slipped).
    servo_hints = ServoHints(posenet="colift", process_std_mm=1.5)

    def __init__(self, trajectory: str = "circular_wave", object_name: str = "prism", mass_kg: float | None = None,
                 obs_mode: str = "real", image_size_px: int = 128, control_rate_hz: float = 10.0,
                 render_mode: str | None = None, reference_depth_mm: float | None = None,
                 speed_mm_s: float = 5.0, rotation_deg: float = 0.0, randomise: bool = False,
                 mount: HorizontalTacTipMount = HorizontalTacTipMount(),
                 termination: TerminationConfig = COLIFT_TERMINATION, payload: str = "light",
                 **base_kwargs) -> None:
        EzPickle.__init__(self, trajectory=trajectory, object_name=object_name, mass_kg=mass_kg, obs_mode=obs_mode,
                          image_size_px=image_size_px, control_rate_hz=control_rate_hz, render_mode=render_mode,
                          reference_depth_mm=reference_depth_mm, speed_mm_s=speed_mm_s,
                          rotation_deg=rotation_deg, randomise=randomise,
                          mount=mount, termination=termination, payload=payload, **base_kwargs)
        if payload not in PAYLOADS:
            raise ValueError(f"payload must be one of {PAYLOADS}, got {payload!r}")
        if reference_depth_mm is None:
            reference_depth_mm = SURFACE_DEPTH_MM + SQUEEZE_MM[payload]
        if trajectory not in TRAJECTORY_CHOICES:
            raise ValueError(f"unknown trajectory {trajectory!r}; expected one of {TRAJECTORY_CHOICES}")
        if object_name not in OBJECT_NAMES:
            raise ValueError(f"unknown object_name {object_name!r}; expected one of {OBJECT_NAMES}")
        if not (isinstance(speed_mm_s, (int, float)) and math.isfinite(speed_mm_s) and speed_mm_s > 0):
            raise ValueError(f"speed_mm_s must be > 0, got {speed_mm_s!r}")
        if not (isinstance(rotation_deg, (int, float)) and abs(rotation_deg) <= ROTATION_LIMIT_DEG):
            raise ValueError(f"rotation_deg must be within +-{ROTATION_LIMIT_DEG} deg, got {rotation_deg!r}")
        if not isinstance(mount, HorizontalTacTipMount):
            raise ValueError(f"the co-lift TacTip lies horizontally: mount must be a HorizontalTacTipMount, "
                             f"got {type(mount).__name__}")
        self.trajectory_name = trajectory
        self.object_name = object_name
        self.mass_kg = mass_kg
        self.payload = payload
        if payload == "heavy":
            # The servo keeps the grasp's shear (ServoController.for_env) plus 0.4 mm along the weight (sensor +y
            # is down: the load's shear is -y), with deadbeat shear gains: carrying a little more than the grasp
            # felt, and at once, keeps the duck and the soft ball from sliding on the plate where the star's path
            # turns (docs/experiments.md, servo_colift_heavy_margin). The heavy grip's images have a GDNN of their
            # own (a sensor's models override it).
            self.servo_hints = replace(self.servo_hints, posenet="colift_heavy", hold_load=True,
                                       load_margin_mm=(0.0, -0.4), shear_gains=(1.0, 0.5))
        self.speed_mm_s = float(speed_mm_s)
        self.rotation_deg = float(rotation_deg)
        self.randomise = bool(randomise)
        self.trajectory: Trajectory | None = None
        self._fresh_scene = False
        self._T_plate_face = np.eye(4)
        self._contact_depth_mm = 0.0
        self._shear_face = np.zeros(6)
        super().__init__(obs_mode=obs_mode, image_size_px=image_size_px, control_rate_hz=control_rate_hz,
                         render_mode=render_mode, reference_depth_mm=reference_depth_mm, mount=mount,
                         termination=termination, **base_kwargs)

    # ------------------------------------------------------------------ hooks
    def _build_scene(self) -> None:
        substeps = max(1, round(_PHYSICS_RATE_HZ / self.control_rate_hz))
        # CoLiftSceneConfig validates the mass with a clear error
        self.scene_config = CoLiftSceneConfig(
            object_name=self.object_name, mass_kg=self.mass_kg, payload=self.payload,
            physics_rate_hz=self.control_rate_hz * substeps, substeps=substeps,
            squeeze_mm=self.reference_depth_mm - SURFACE_DEPTH_MM, tactip=TacTipConfig(image_size_px=128),
            **(FIRM_TIP if self.payload == "heavy" else {}))
        self.scene = CoLiftScene(self.scene_config)
        self.leader: SimMG400 = self._add_arm(LEADER_T_WORLD_BASE, LEADER_START_POSE_MM_DEG, T_FLANGE_PLATE)
        spec = self.scene.spec
        # the nominal start (the exact one comes from the scene at reset): object against the plate, squeezed
        T_world_plate = self.leader.T_world_tool()
        T_world_sensor = T_world_plate @ translation_matrix(z_mm=spec.size_mm[2] - self.scene_config.squeeze_mm)
        start_pose = self.flange_pose_for_sensor(FOLLOWER_T_WORLD_BASE, T_world_sensor @ _T_SENSOR_TURN)
        self._add_follower(FOLLOWER_T_WORLD_BASE, start_pose)
        self.face_half_extents_mm = (spec.size_mm[0] / 2.0, spec.size_mm[1] / 2.0)
        # Visual copies of the physics bodies in the env's world: the TacTip renders the object's copy; the
        # plate's copy is drawn only in the scene view. This world is never stepped.
        self._object_copy = spawn_object(self.world, spec, T_world_plate @ translation_matrix(z_mm=500.0))
        self._plate_copy = -1
        if self.render_mode is not None:
            import pybullet

            half_m = (np.asarray(self.scene_config.plate_size_mm) / 2000.0).tolist()
            visual = self.world.client.createVisualShape(
                pybullet.GEOM_BOX, halfExtents=half_m, visualFramePosition=[0.0, 0.0, -half_m[2]],
                rgbaColor=[0.3, 0.3, 0.3, 1.0])
            self._plate_copy = self.world.client.createMultiBody(baseVisualShapeIndex=visual)

    def _reset_scene(self, rng: np.random.Generator, options: dict | None) -> None:
        options = options or {}
        name = self.trajectory_name
        if name == "random":
            name = COLIFT_TRAJECTORIES[int(rng.integers(len(COLIFT_TRAJECTORIES)))]
        scale, speed, rotation, offset = 1.0, self.speed_mm_s, self.rotation_deg, np.zeros(3)
        if self.randomise:
            scale = float(rng.uniform(0.7, 1.3))
            speed *= float(rng.uniform(0.7, 1.3))
            rotation *= float(rng.uniform(-1.0, 1.0))
            offset = rng.uniform(-10.0, 10.0, 3)
        if "start_offset_mm" in options:
            offset = np.asarray(options["start_offset_mm"], dtype=np.float64).reshape(-1)
            if offset.shape != (3,) or not np.all(np.abs(offset) <= START_OFFSET_LIMIT_MM):
                raise ValueError(f"options['start_offset_mm'] must be (x, y, z) world mm within "
                                 f"+-{START_OFFSET_LIMIT_MM} mm, got {options['start_offset_mm']!r}")
        self.trajectory = Trajectory(TrajectoryConfig(name, scale=scale, speed_mm_s=speed, rotation_deg=rotation))
        self.leader.reset(LEADER_START_POSE_MM_DEG + np.append(offset, 0.0))
        T_world_plate = self.leader.T_world_tool()
        self._T_world_plate_start = T_world_plate
        T_world_sensor = self.scene.reset(T_world_plate)
        try:
            self.follower.reset(self.flange_pose_for_sensor(FOLLOWER_T_WORLD_BASE, T_world_sensor))
        except ValueError as error:
            raise ValueError(f"the follower cannot reach the start grip (start offset {offset.tolist()} mm): "
                             f"{error}") from error
        # the object's face under the sensor, carried with the plate: the sensor sits at the reference depth in
        # its work frame (see the base module's frames)
        T_world_face = T_world_sensor @ translation_matrix(z_mm=-self.reference_depth_mm) @ self.T_work_face
        self._T_plate_face = invert(T_world_plate) @ T_world_face
        self._fresh_scene = True  # the scene has just settled: the base's _sync_scene must not step it again

    def _T_world_plate_at(self, time_s: float) -> np.ndarray:
        """The plate's pose along the trajectory: world offset, and a turn about the vertical through its face."""
        dx, dy, dz, dr = self.trajectory.offset_at(time_s)
        T_world_plate = rz_matrix(dr) @ self._T_world_plate_start
        T_world_plate[:3, 3] = self._T_world_plate_start[:3, 3] + (dx, dy, dz)
        return T_world_plate

    def _command_scene(self, time_s: float, dt_s: float) -> None:
        self.leader.servo_tool(self._T_world_plate_at(time_s), dt_s)

    def _sync_scene(self) -> None:
        if self._fresh_scene:
            self._fresh_scene = False
        else:
            self.scene.step(self.leader.T_world_tool(), self.follower.T_world_tool())
        client = self.world.client
        client.resetBasePositionAndOrientation(self._object_copy, *pybullet_pose_fast(self.scene.object_pose()))
        if self._plate_copy >= 0:
            client.resetBasePositionAndOrientation(self._plate_copy, *pybullet_pose_fast(self.scene.plate_pose()))

    def _T_world_face(self) -> np.ndarray:
        return self.leader.T_world_tool() @ self._T_plate_face

    def _measure(self) -> ContactState:
        """The base's measures relative to the object's face as carried by the plate (depth, contact error), with
        the physical contact and the shear over the object itself from the scene."""
        state = super()._measure()
        self._shear_face = state.shear_sensor  # over the face as carried by the plate: what the oracle sees
        self._contact_depth_mm = self.scene.contact_depth_mm()
        return replace(state, in_contact=self._contact_depth_mm > 0.0, shear_sensor=self.scene.shear_sensor())

    def _yaw_error_deg(self, state: ContactState) -> float:
        """The sensor axis's turn about the vertical from its target's (the face normal, reversed)."""
        error = heading_deg(state.T_world_sensor[:3, 2]) - heading_deg(-self._T_world_face()[:3, 2])
        return float((error + 180.0) % 360.0 - 180.0)

    def _oracle_variables(self, state: ContactState) -> np.ndarray:
        values = np.array([state.depth_mm, self._shear_face[0], self._shear_face[1], self._yaw_error_deg(state)])
        return np.clip(values, -TRUE_POSE_SHEAR_LIMIT, TRUE_POSE_SHEAR_LIMIT).astype(np.float32)

    def _termination(self, state: ContactState, arm_error: str) -> str:
        """Co-lift's reasons (the object, not the face as carried by the plate, decides contact and depth)."""
        config = self.termination_config
        if arm_error:
            return "arm_limit"
        if self.scene.dropped():
            return "dropped"
        if state.contact_error_mm > config.max_contact_error_mm:
            return "contact_error"
        if self._contact_depth_mm > config.max_penetration_mm:
            return "too_deep"
        return ""

    def _task_info(self) -> dict[str, Any]:
        return {
            "trajectory": self.trajectory.config.name if self.trajectory is not None else "",
            "object_name": self.object_name,
            "dropped": self.scene.dropped(),
            "contact_depth_mm": self._contact_depth_mm,
            "object_slip_mm": self.scene.object_slip_mm(),
            "yaw_error_deg": self._yaw_error_deg(self._state),
        }

    def _scene_target_world_mm(self) -> np.ndarray:
        return self.scene.object_pose()[:3, 3]

    def close(self) -> None:
        self.scene.close()
        super().close()


def make_colift_vector_env(num_envs: int = 1, max_episode_steps: int | None = 500, workers: int | None = None,
                           translate_in: str = "workers", start_method: str | None = None, **env_kwargs: Any):
    """The ``vector_entry_point`` of ``SimShearCoLift-v0``: a
    :class:`~simshear_gym.envs.vector.SimShearVectorEnv` of co-lift sub-envs (batched translation)."""
    from simshear_gym.envs.vector import SimShearVectorEnv

    return SimShearVectorEnv("simshear_gym.envs.colift:SimShearCoLiftEnv", num_envs, env_kwargs, max_episode_steps,
                             workers, translate_in, start_method)
