"""The co-lift scene: a leader's plate and a follower's TacTip squeeze an object and carry it by friction alone.

This is the physics of ``SimShearCoLift-v0``: the env drives it with two poses per control step and reads
images, depths and shear back.

Frames (mm, world z up):
    plate:  origin at the centre of the plate's contact face, +z the face's outward normal (towards the
            object and the tip), +y up when the plate is upright (:func:`upright_plate`), +x = y x z.
    object: origin at its centre of mass, axes as in :mod:`simshear_gym.sim.objects`; at reset it is the
            plate frame shifted along plate +z until the object touches the face (+z the grip axis, +y up).
    sensor: the TacTip's TCP at the dome apex, +z out of the dome (towards the plate); at reset
            ``T_plate_sensor`` is the plate frame turned 180 deg about x (sensor y down, so image rows run
            down the world like a camera's) and shifted along the grip axis so the dome penetrates the object
            by ``squeeze_mm``.
    work:   fixed in the object; the sensor frame at reset shifted back by ``squeeze_mm``, so a sensor pose in
            it has ``z`` = indentation like the labels' work frame; the shear is measured in it.

Physics choice: both grippers are **driven rigid bodies** and the object is a free body held by contact
friction only (no constraint ever attaches it).
    * The plate (a box) and the tip (a sphere of the dome's radius, centred ``dome_radius_mm`` behind the apex)
      have a large mass (``drive_mass_kg``, 1 kg against a 30 g object). Before every
      physics step each gets the velocity that carries it from where it is to the next sub-step pose
      (poses interpolated linearly / by slerp between control steps), so they follow the commanded poses
      up to the ~0.03 mm a 1.5 N contact pushes them back within one step, and - unlike bodies
      teleported with ``resetBasePositionAndOrientation`` - they have real velocities, so friction carries
      the object along instead of letting it lag and slip.
    * The tip's contact is soft: an implicit spring-damper (``contactStiffness`` / ``contactDamping``,
      default 500 N/m, 5 N s/m), about a real TacTip's few newtons over a few millimetres. The squeeze is then
      the dome's deformation: at 3 mm the grip force is about 1.5 N, five times what a 30 g object needs at
      friction 1 on two faces. The plate's contact is Bullet's rigid one; a soft object (the brain) adds its
      own compliance in series on both sides.
    * Torsion and rolling: a soft fingertip's contact patch (about 11 mm in radius at a 3 mm squeeze) resists
      the object turning about the grip axis and rolling over the skin; Bullet's single contact point does
      not, so a convex object (egg, duck) gripped at two points pivots like a pendulum and rolls along the
      plate when the tip moves across it. The tip therefore carries spinning friction
      (``tip_torsion_arm_mm``) and rolling friction (``tip_rolling_arm_mm``), the plate a small spinning
      friction (``plate_torsion_arm_mm``) plus a negligible rolling friction, without which Bullet ignores
      spinning friction altogether.
    * Skin shear: a TacTip's skin is compliant across its axis as well: when the sensor lags the object, the
      skin stays on the object and shears (the markers move: what the image shows), pulling on the object
      with a force that grows with the shear, well below what the plate's friction holds. The tip body is
      therefore the skin's contact surface: along the optical axis it is driven to the commanded sensor pose
      like the plate, across it a critically damped spring (``skin_shear_stiffness_npm``, 100 N/m) holds it
      to the commanded pose. :meth:`CoLiftScene.sensor_pose` is the sensor (the commanded pose, rigid on the
      arm), :meth:`CoLiftScene.skin_pose` the tip body, and the shear is the skin's deflection (the sensor in
      the skin's frame). With a rigid tip (stiffness 0, no rolling friction) a 3 mm lag instead rolls or
      slides the object 1.5 mm along the plate and shows as 0.2-0.4 mm of shear, so the image cannot tell the
      follower how far it lags; with the skin, 3 mm of lag across or down leaves every object within 0.5 mm of
      its place and shows as 2-3 mm of shear (``tests/test_colift_scene.py``).
    * Friction anchors (``frictionAnchor``) on every body: Bullet's velocity-level friction otherwise lets a
      contact under a steady tangential load creep (the prism crept 1-3 mm along the plate under the skin's
      pull); an anchor holds the contact point until the friction cone is exceeded.
    * The soft brain's own contact patches resist rolling (:data:`~simshear_gym.sim.objects.OBJECTS`).
    * The TacTip image is **not** the physics contact: it is :class:`TacTip`'s render of the object's
      penetration into the undeformed dome at the sensor's pose. The tip body has a fully
      transparent visual shape, which PyBullet's TinyRenderer skips (with no visual shape it would render the
      collision sphere, i.e. the dome itself). Because the contact is soft, the overlap of object and dome is
      the deformation and is what the image shows; :meth:`CoLiftScene.contact_depth_mm` reads the same overlap
      from the collision shapes.

Rates: physics at ``physics_rate_hz`` (240 Hz), ``substeps`` physics steps per control step (12: 20 Hz).
Cost (shared 2-core machine): about 2-3 ms per control step of physics plus 1.6-3 ms per 128 px image (the
duck's 4k-triangle visual mesh is the slowest to render).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pybullet
from scipy.spatial.transform import Rotation

from simshear_gym.sim.objects import OBJECTS, ObjectSpec, object_spec, spawn_object
from simshear_gym.sim.shear import ShearTracker, ShearTrackerConfig
from simshear_gym.sim.tactip import TacTip, TacTipConfig
from simshear_gym.sim.world import ClosedOnExit, World, WorldConfig
from simshear_gym.transforms import (
    invert,
    matrix_to_pose,
    matrix_to_pybullet,
    rotation_to_quaternion_xyzw,
)

_FAR_MM = 300.0  # where bodies wait while the others are measured at reset
_ROLLING_FRICTION_M = 1e-6


@dataclass(frozen=True)
class CoLiftSceneConfig:
    """Settings of a co-lift scene.

    Attributes:
        object_name: one of :data:`simshear_gym.sim.objects.OBJECTS` (prism, egg, brain, ducky).
        mass_kg: object mass; None keeps the object's default (30 g for all four light ones).
        payload: ``light`` (:data:`~simshear_gym.sim.objects.OBJECTS`) or ``heavy``
            (:data:`~simshear_gym.sim.objects.HEAVY_OBJECTS`, 0.5-2.0 kg: carry them with :data:`FIRM_TIP`).
        physics_rate_hz: physics steps per second.
        substeps: physics steps per control step (control period = substeps / physics_rate_hz).
        squeeze_mm: default squeeze at reset: penetration of the object into the dome along its normal.
        tip_contact_stiffness_npm: stiffness of the tip's soft contact (N/m).
        tip_contact_damping_nspm: damping of the tip's soft contact (N s/m).
        tip_friction: friction coefficient of the tip's skin (Bullet multiplies it with the object's).
        plate_friction: friction coefficient of the plate.
        tip_torsion_arm_mm: Bullet's spinning friction of the tip (torque limit / normal force, mm): the soft
            dome's contact patch resists the object turning about the grip axis (uniform pressure on a patch
            of radius a gives 2a/3, about 7 mm at a 3 mm squeeze; 5 mm is conservative).
        plate_torsion_arm_mm: the same for the plate (a rigid plate on a convex object: a small patch).
        tip_rolling_arm_mm: Bullet's rolling friction of the tip (torque limit / normal force, mm): the same patch
            resists the object rolling over the skin (turning about an axis across the grip).
        plate_rolling_arm_mm: the same for the plate (0: a rigid plate under a rigid object; a pad would add some).
        skin_shear_stiffness_npm: tangential stiffness of the skin between the sensor and its contact surface
            (N/m): the tip body is held to the commanded sensor pose by this spring (critically damped) across
            the optical axis, so a follower lag shears the skin instead of dragging the object along the plate;
            0 = a rigid tip (the tip body follows the commanded pose exactly).
        plate_size_mm: plate extent (x, y, thickness z).
        drive_mass_kg: mass of each driven body (plate, tip); large against the object so it is not pushed.
        settle_s: time the grip is held still at reset so the contacts reach equilibrium.
        drop_threshold_mm: the object counts as dropped once its centre is this far from its place relative
            to the plate at the end of reset.
        solver_iterations: constraint solver iterations per physics step.
        shear_from_placement: the shear counts from the moment the dome is placed on the object, before the grip
            settles under the object's weight, so the skin's deflection under the load shows as shear (a heavy
            object's weight is what the follower must read); False: from the end of the settle (a light object's
            few hundredths of a millimetre of sag are not shear).
        tactip: TacTip geometry and image settings (the dome radius also sizes the tip's collision sphere).
        shear: stick-slip limits of the shear tracker.
    """

    object_name: str = "prism"
    mass_kg: float | None = None
    payload: str = "light"
    physics_rate_hz: float = 240.0
    substeps: int = 12
    squeeze_mm: float = 3.0
    tip_contact_stiffness_npm: float = 500.0
    tip_contact_damping_nspm: float = 5.0
    tip_friction: float = 1.0
    plate_friction: float = 1.0
    tip_torsion_arm_mm: float = 5.0
    plate_torsion_arm_mm: float = 1.0
    tip_rolling_arm_mm: float = 10.0
    plate_rolling_arm_mm: float = 0.0
    skin_shear_stiffness_npm: float = 100.0
    plate_size_mm: tuple[float, float, float] = (60.0, 60.0, 6.0)
    drive_mass_kg: float = 1.0
    settle_s: float = 0.25
    drop_threshold_mm: float = 20.0
    solver_iterations: int = 50
    shear_from_placement: bool = False
    tactip: TacTipConfig = field(default_factory=TacTipConfig)
    shear: ShearTrackerConfig = field(default_factory=ShearTrackerConfig)

    def __post_init__(self) -> None:
        if self.object_name not in OBJECTS:
            raise ValueError(f"unknown object {self.object_name!r}; expected one of {sorted(OBJECTS)}")
        object_spec(self.object_name, self.mass_kg, self.payload)  # validates the payload and the mass
        if not 10.0 <= self.physics_rate_hz <= 10000.0:
            raise ValueError(f"physics_rate_hz must be in [10, 10000] Hz, got {self.physics_rate_hz}")
        if self.substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {self.substeps}")
        _check_squeeze(self.squeeze_mm, self.tactip)
        if self.tip_contact_stiffness_npm <= 0 or self.tip_contact_damping_nspm < 0:
            raise ValueError(
                "tip contact needs stiffness > 0 N/m and damping >= 0 N s/m, got "
                f"{self.tip_contact_stiffness_npm} and {self.tip_contact_damping_nspm}"
            )
        if self.skin_shear_stiffness_npm < 0:
            raise ValueError(f"skin_shear_stiffness_npm must be >= 0 N/m, got {self.skin_shear_stiffness_npm}")
        if min(self.tip_friction, self.plate_friction, self.tip_torsion_arm_mm, self.plate_torsion_arm_mm,
               self.tip_rolling_arm_mm, self.plate_rolling_arm_mm) < 0:
            raise ValueError(
                f"friction must be >= 0, got tip {self.tip_friction}, plate {self.plate_friction}, torsion arms "
                f"{self.tip_torsion_arm_mm} mm and {self.plate_torsion_arm_mm} mm, tip rolling arm "
                f"{self.tip_rolling_arm_mm} mm, plate rolling arm {self.plate_rolling_arm_mm} mm"
            )
        if len(self.plate_size_mm) != 3 or min(self.plate_size_mm) <= 0:
            raise ValueError(f"plate_size_mm must be three positive extents, got {self.plate_size_mm}")
        if self.drive_mass_kg <= 0 or self.settle_s < 0 or self.drop_threshold_mm <= 0:
            raise ValueError(
                "need drive_mass_kg > 0, settle_s >= 0 and drop_threshold_mm > 0, got "
                f"{self.drive_mass_kg}, {self.settle_s}, {self.drop_threshold_mm}"
            )
        if self.solver_iterations < 1:
            raise ValueError(f"solver_iterations must be >= 1, got {self.solver_iterations}")

    @property
    def time_step_s(self) -> float:
        return 1.0 / self.physics_rate_hz

    @property
    def control_period_s(self) -> float:
        return self.substeps / self.physics_rate_hz

    @property
    def object(self) -> ObjectSpec:
        return object_spec(self.object_name, self.mass_kg, self.payload)


FIRM_TIP: dict = {"tip_contact_stiffness_npm": 4000.0, "tip_contact_damping_nspm": 14.0,
                  "skin_shear_stiffness_npm": 2000.0, "shear_from_placement": True, "plate_friction": 2.0}
"""The heavy co-lift's grip (:class:`CoLiftSceneConfig` fields): a firm dome (4 N/mm: about 16 N at a 4 mm squeeze,
ten times the soft default's 1.5 N at 3 mm) whose skin holds a tangential load at 2 N/mm, the shear counted from
placement so that the load's deflection shows, against a leader's plate with a rubber pad (friction 2; Bullet
multiplies it with the object's 1). The plate's static friction then holds the object with a margin, so the
plate's moves drag the object and show on the skin as for a light one, while the load's share on the skin stays as a
steady shear from the first image (0.6 mm for the 2 kg block, 2.1 mm for the 1.5 kg egg). With a plate of friction
1 the plate sat at its friction limit: it slid past the object whenever it moved, its moves never reached the skin,
and a follower reading the skin dropped the block and the soft ball (docs/experiments.md, servo_colift_heavy). Damping
scales with the square root of the stiffness (the soft tip's 5 N s/m at 500 N/m)."""


def _check_squeeze(squeeze_mm: float, tactip: TacTipConfig) -> None:
    if not 0.0 <= squeeze_mm < tactip.dome_radius_mm:
        raise ValueError(f"squeeze_mm must be in [0, {tactip.dome_radius_mm}) mm, got {squeeze_mm}")


def upright_plate(position_world_mm: np.ndarray, yaw_deg: float = 0.0) -> np.ndarray:
    """T_world_plate of an upright plate at ``position_world_mm`` facing world +y turned by ``yaw_deg`` about z.

    The plate's +y is world up and its +z (towards the object and the follower) is horizontal.
    """
    rotation = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix() @ np.array(
        [[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]  # columns: plate x, y, z in the world
    )
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = np.asarray(position_world_mm, dtype=np.float64)
    return transform


def translation_matrix(x_mm: float = 0.0, y_mm: float = 0.0, z_mm: float = 0.0) -> np.ndarray:
    """4x4 (mm) a pure translation."""
    transform = np.eye(4)
    transform[:3, 3] = [x_mm, y_mm, z_mm]
    return transform


_T_PLATE_SENSOR_TURN = np.diag([1.0, -1.0, -1.0, 1.0])  # 180 deg about x: sensor z faces the plate


def _check_transform(name: str, value: np.ndarray) -> np.ndarray:
    matrix = np.asarray(value, dtype=np.float64)
    if matrix.shape != (4, 4) or not np.allclose(matrix[:3, :3] @ matrix[:3, :3].T, np.eye(3), atol=1e-6):
        raise ValueError(f"{name} must be a 4x4 rigid transform (mm) with a rotation block, got {matrix!r}")
    return matrix


class CoLiftScene(ClosedOnExit):
    """A plate, a TacTip and one object in their own :class:`World`. Close it (or use ``with``) when done.

    Call :meth:`reset` first, then :meth:`step` once per control step with the plate's and the sensor's new
    world poses. Every reset builds a fresh world (a new PyBullet client, 20-70 ms with the object), so an
    episode depends on nothing but its reset arguments and commands, bit for bit: Bullet's broadphase keeps
    history across body removal, which otherwise changes results in the 7th digit. Anything an owner adds to
    :attr:`world` must be added again after each reset.
    """

    def __init__(self, config: CoLiftSceneConfig = CoLiftSceneConfig()) -> None:
        self.config = config
        self.spec = config.object
        self._world: World | None = None
        self._plate = self._tip = self._object = -1
        self._tactips: dict[int, TacTip] = {}
        self._shear = ShearTracker(config.shear)
        self._shear_sensor = np.zeros(6)
        self._T_world_plate_cmd = np.eye(4)
        self._T_world_sensor_cmd = np.eye(4)
        self._sensor_step_m = np.zeros(3)
        self._T_plate_sensor0 = np.eye(4)
        self._T_plate_object0 = np.eye(4)
        self._T_object_work = np.eye(4)
        self._T_skin_work = np.eye(4)
        self._dropped = False
        self._gravity_step_mps = np.zeros(3)

    @property
    def world(self) -> World:
        """The world of the current episode (replaced at every reset)."""
        if self._world is None:
            raise RuntimeError("call reset() first: the scene builds its world at reset")
        return self._world

    # -- building -----------------------------------------------------------------------------------------

    def _create_driven(self, collision: int, visual: int, lateral_friction: float, torsion_arm_mm: float,
                       rolling_arm_mm: float = 0.0) -> int:
        client = self.world.client
        body = client.createMultiBody(
            baseMass=self.config.drive_mass_kg, baseCollisionShapeIndex=collision, baseVisualShapeIndex=visual,
            basePosition=[0.0, 0.0, _FAR_MM / 1000.0], useMaximalCoordinates=True,
        )
        # Bullet applies spinning friction only where the combined rolling friction is > 0: a negligible one
        # (1 um: 1e-6 N m per N) switches it on.
        client.changeDynamics(
            body, -1, lateralFriction=lateral_friction, spinningFriction=torsion_arm_mm / 1000.0,
            rollingFriction=max(rolling_arm_mm / 1000.0, _ROLLING_FRICTION_M), linearDamping=0.0, angularDamping=0.0,
            activationState=pybullet.ACTIVATION_STATE_DISABLE_SLEEPING, frictionAnchor=1,
        )
        return body

    def _create_plate(self) -> int:
        client = self.world.client
        half_m = (np.asarray(self.config.plate_size_mm) / 2000.0).tolist()
        centre_m = [0.0, 0.0, -half_m[2]]  # the body frame is the plate frame, on the contact face
        collision = client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half_m, collisionFramePosition=centre_m)
        visual = client.createVisualShape(
            pybullet.GEOM_BOX, halfExtents=half_m, visualFramePosition=centre_m, rgbaColor=[0.3, 0.3, 0.3, 1.0]
        )
        return self._create_driven(collision, visual, self.config.plate_friction, self.config.plate_torsion_arm_mm,
                                   self.config.plate_rolling_arm_mm)

    def _create_tip(self) -> int:
        client = self.world.client
        radius_m = self.config.tactip.dome_radius_mm / 1000.0
        centre_m = [0.0, 0.0, -radius_m]  # the body frame is the sensor frame, at the apex
        collision = client.createCollisionShape(pybullet.GEOM_SPHERE, radius=radius_m, collisionFramePosition=centre_m)
        visual = client.createVisualShape(  # transparent: TinyRenderer skips it (see the module docstring)
            pybullet.GEOM_SPHERE, radius=radius_m, visualFramePosition=centre_m, rgbaColor=[1.0, 1.0, 1.0, 0.0]
        )
        body = self._create_driven(collision, visual, self.config.tip_friction, self.config.tip_torsion_arm_mm,
                                   self.config.tip_rolling_arm_mm)
        client.changeDynamics(
            body, -1, contactStiffness=self.config.tip_contact_stiffness_npm,
            contactDamping=self.config.tip_contact_damping_nspm,
        )
        return body

    # -- episode --------------------------------------------------------------------------------------------

    def reset(self, T_world_plate: np.ndarray, squeeze_mm: float | None = None) -> np.ndarray:
        """Place the plate at ``T_world_plate``, the object against it and the tip squeezing it; hold still for
        ``settle_s``. Returns T_world_sensor, the sensor's commanded pose (also the tracking target's start).

        Args:
            T_world_plate: 4x4 (mm) plate pose; see :func:`upright_plate`.
            squeeze_mm: penetration of the object into the dome along the contact normal at placement
                (default ``config.squeeze_mm``).
        """
        T_world_plate = _check_transform("T_world_plate", T_world_plate)
        squeeze_mm = self.config.squeeze_mm if squeeze_mm is None else float(squeeze_mm)
        _check_squeeze(squeeze_mm, self.config.tactip)
        if self._world is not None:
            self._world.close()
        config = self.config
        self._world = World(WorldConfig(time_step_s=config.time_step_s, solver_iterations=config.solver_iterations))
        self._gravity_step_mps = np.array([0.0, 0.0, self._world.config.gravity_mps2 * config.time_step_s])
        self._tactips = {}
        client = self._world.client
        self._plate = self._create_plate()
        self._tip = self._create_tip()
        client.setCollisionFilterPair(self._plate, self._tip, -1, -1, 0)  # two driven bodies do not collide
        far = translation_matrix(z_mm=_FAR_MM)
        self._place(self._tip, T_world_plate @ far @ far @ _T_PLATE_SENSOR_TURN)
        self._place(self._plate, T_world_plate)
        self._object = spawn_object(self._world, self.spec, T_world_plate @ far)
        client.changeDynamics(self._object, -1, activationState=pybullet.ACTIVATION_STATE_DISABLE_SLEEPING,
                              frictionAnchor=1)

        # the object touches the plate: move it in by its distance to the face
        gap_mm = self._distance_mm(self._plate, self._object)
        T_world_object = T_world_plate @ translation_matrix(z_mm=_FAR_MM - gap_mm)
        self._place(self._object, T_world_object)
        # the tip comes in along the grip axis until it overlaps the object by squeeze_mm (a few Newton steps:
        # on a curved surface the distance changes more slowly than the axial offset)
        offset_mm = _FAR_MM
        for _ in range(20):
            self._place(self._tip, T_world_object @ translation_matrix(z_mm=offset_mm) @ _T_PLATE_SENSOR_TURN)
            error_mm = self._distance_mm(self._tip, self._object) + squeeze_mm
            if abs(error_mm) < 1e-3:
                break
            offset_mm -= error_mm
        T_world_sensor = T_world_object @ translation_matrix(z_mm=offset_mm) @ _T_PLATE_SENSOR_TURN

        self._T_world_plate_cmd, self._T_world_sensor_cmd = T_world_plate, T_world_sensor
        self._sensor_step_m = T_world_sensor[:3, 3] / 1000.0
        self._T_plate_sensor0 = invert(T_world_plate) @ T_world_sensor
        self._T_object_work = invert(T_world_object) @ T_world_sensor @ translation_matrix(z_mm=-squeeze_mm)
        self._T_skin_work = translation_matrix(z_mm=-squeeze_mm)  # the skin body sits at the sensor pose at placement
        self._shear.reset()
        self._dropped = False
        if self.config.shear_from_placement:
            self._update_shear()  # the contact begins at placement: the settle's deflection is shear
        self._hold(T_world_plate, T_world_sensor, round(self.config.settle_s * self.config.physics_rate_hz))
        self._T_plate_object0 = invert(T_world_plate) @ self.object_pose()
        self._update_shear()
        return T_world_sensor.copy()

    def step(self, T_world_plate: np.ndarray, T_world_sensor: np.ndarray) -> None:
        """Move the plate and the sensor to new world poses (4x4, mm) over one control step of physics."""
        if self._world is None:
            raise RuntimeError("call reset() before step(): the scene builds its world at reset")
        T_world_plate = _check_transform("T_world_plate", T_world_plate)
        T_world_sensor = _check_transform("T_world_sensor", T_world_sensor)
        fractions = np.arange(1, self.config.substeps + 1) / self.config.substeps
        plates = _interpolate(self._T_world_plate_cmd, T_world_plate, fractions)
        sensors = _interpolate(self._T_world_sensor_cmd, T_world_sensor, fractions)
        for plate, sensor in zip(zip(*plates), zip(*sensors)):
            self._drive(plate, sensor)
        self._T_world_plate_cmd, self._T_world_sensor_cmd = T_world_plate, T_world_sensor
        self._update_shear()

    def _hold(self, T_world_plate: np.ndarray, T_world_sensor: np.ndarray, n_steps: int) -> None:
        plate = (T_world_plate[:3, 3] / 1000.0, rotation_to_quaternion_xyzw(T_world_plate[:3, :3]))
        sensor = (T_world_sensor[:3, 3] / 1000.0, rotation_to_quaternion_xyzw(T_world_sensor[:3, :3]))
        for _ in range(n_steps):
            self._drive(plate, sensor)

    def _drive(self, plate: tuple[np.ndarray, np.ndarray], sensor: tuple[np.ndarray, np.ndarray]) -> None:
        """One physics step in which the plate and the tip move to the given (position m, quaternion xyzw).

        Bullet adds gravity to the velocity before the contacts and the position update see it, so the set
        velocity holds the step's gravity back in advance (gravity compensation without another call).
        """
        client = self.world.client
        rate = self.config.physics_rate_hz
        for body, (position_m, quaternion) in ((self._plate, plate), (self._tip, sensor)):
            now_m, now_quaternion = client.getBasePositionAndOrientation(body)
            turn = _quaternion_multiply(quaternion, _quaternion_conjugate(now_quaternion))
            velocity_mps = (position_m - now_m) * rate
            if body == self._tip and self.config.skin_shear_stiffness_npm > 0:
                velocity_mps = self._skin_velocity_mps(np.asarray(now_m), position_m, quaternion, velocity_mps)
            client.resetBaseVelocity(body, (velocity_mps + self._gravity_step_mps).tolist(),
                                     (_quaternion_to_rotvec(turn) * rate).tolist())
        self._sensor_step_m = sensor[0]
        client.stepSimulation()

    def _skin_velocity_mps(self, now_m: np.ndarray, target_m: np.ndarray, quaternion: np.ndarray,
                           drive_mps: np.ndarray) -> np.ndarray:
        """The tip's velocity for the next physics step with a compliant skin: along the optical axis it is
        driven to the target as a rigid tip; across it, its velocity (which carries the contact impulses of the
        last step) is accelerated by a critically damped spring to the commanded sensor position (semi-implicit
        Euler, stable for sqrt(k / m) * dt << 1: 0.07 at 300 N/m, 1 kg, 240 Hz)."""
        config = self.config
        dt = config.time_step_s
        axis = np.reshape(self.world.client.getMatrixFromQuaternion(quaternion), (3, 3))[:, 2]
        velocity = np.asarray(self.world.client.getBaseVelocity(self._tip)[0])
        sensor_velocity = (target_m - self._sensor_step_m) / dt
        stiffness, mass = config.skin_shear_stiffness_npm, config.drive_mass_kg
        damping = 2.0 * np.sqrt(stiffness * mass)
        offset = now_m - target_m
        accel = (-stiffness * offset - damping * (velocity - sensor_velocity)) / mass
        across = velocity + accel * dt
        across -= np.dot(across, axis) * axis
        return across + np.dot(drive_mps, axis) * axis

    def _place(self, body: int, T_world_body: np.ndarray) -> None:
        position_m, quaternion = matrix_to_pybullet(T_world_body)
        self.world.client.resetBasePositionAndOrientation(body, position_m, quaternion)
        self.world.client.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])

    def _distance_mm(self, body_a: int, body_b: int) -> float:
        points = self.world.client.getClosestPoints(body_a, body_b, 2.0 * _FAR_MM / 1000.0)
        if not points:
            raise RuntimeError("reset geometry: no closest points between the bodies (object spawn failed?)")
        return 1000.0 * min(point[8] for point in points)

    def _update_shear(self) -> None:
        if self.config.skin_shear_stiffness_npm > 0:  # the skin's own deflection is the shear the markers show
            T_world_work = self.skin_pose() @ self._T_skin_work
        else:
            T_world_work = self.object_pose() @ self._T_object_work
        pose_work = matrix_to_pose(invert(T_world_work) @ self.sensor_pose())
        self._shear_sensor = self._shear.update(pose_work, self.contact_depth_mm() > 0.0)

    # -- state ----------------------------------------------------------------------------------------------

    def _body_pose(self, body: int) -> np.ndarray:
        position_m, quaternion = self.world.client.getBasePositionAndOrientation(body)
        transform = np.eye(4)
        transform[:3, :3] = np.reshape(self.world.client.getMatrixFromQuaternion(quaternion), (3, 3))
        transform[:3, 3] = 1000.0 * np.asarray(position_m)
        return transform

    def object_pose(self) -> np.ndarray:
        """T_world_object (4x4, mm): the object's centre of mass and axes now."""
        return self._body_pose(self._object)

    def sensor_pose(self) -> np.ndarray:
        """T_world_sensor (4x4, mm): the sensor body (camera and dome base, rigid on the arm) at its latest
        commanded pose."""
        return self._T_world_sensor_cmd.copy()

    def skin_pose(self) -> np.ndarray:
        """T_world of the tip body now (4x4, mm): the skin's contact surface, off the sensor pose by the skin's
        shear (and by ~0.03 mm along the axis, the soft contact's push)."""
        return self._body_pose(self._tip)

    def plate_pose(self) -> np.ndarray:
        """T_world_plate (4x4, mm) of the plate body now."""
        return self._body_pose(self._plate)

    def T_world_sensor_target(self) -> np.ndarray:
        """The sensor's tracking target: its pose relative to the plate at reset, carried along with the plate's
        latest commanded pose (4x4, mm)."""
        return self._T_world_plate_cmd @ self._T_plate_sensor0

    def pose_target_sensor(self) -> np.ndarray:
        """The sensor's pose in its target frame (x, y, z mm, Rx, Ry, Rz deg): the tracking error; z > 0 is
        deeper into the object than at reset."""
        return matrix_to_pose(invert(self.T_world_sensor_target()) @ self.sensor_pose())

    def object_slip_mm(self) -> float:
        """How far the object's centre has moved relative to the plate since the end of reset (mm)."""
        T_plate_object = invert(self.plate_pose()) @ self.object_pose()
        return float(np.linalg.norm(T_plate_object[:3, 3] - self._T_plate_object0[:3, 3]))

    def contact_depth_mm(self) -> float:
        """Penetration of the object into the tip's dome along the optical axis (mm, 0 out of contact), from the
        collision shapes: the deepest closest-point pair projected on the sensor's +z."""
        points = self.world.client.getClosestPoints(self._tip, self._object, 0.0)
        if not points:
            return 0.0
        axis = self.skin_pose()[:3, 2]
        depth_m = max(float(np.dot(np.subtract(point[5], point[6]), axis)) for point in points)
        return max(1000.0 * depth_m, 0.0)

    def touching(self) -> tuple[bool, bool]:
        """(tip touches the object, plate touches the object) after the last physics step."""
        client, body = self.world.client, self._object
        return bool(client.getContactPoints(self._tip, body)), bool(client.getContactPoints(self._plate, body))

    def shear_sensor(self) -> np.ndarray:
        """(6,) shear in the sensor frame (x, y, z mm, Rx, Ry, Rz deg): the sensor's motion relative to the object
        since the contact began (:class:`ShearTracker`, stick-slip limited); zeros out of contact."""
        return self._shear_sensor.copy()

    def dropped(self) -> bool:
        """True once the object has slipped more than ``drop_threshold_mm`` from its place relative to the plate
        or touches neither the plate nor the tip; stays true until the next reset."""
        if not self._dropped:
            tip, plate = self.touching()
            self._dropped = self.object_slip_mm() > self.config.drop_threshold_mm or not (tip or plate)
        return self._dropped

    def push_object(self, velocity_mm_s) -> None:
        """Set the object's velocity (world, mm/s; a knock, for fault tests: the grip must lose it)."""
        if self._world is None:
            raise RuntimeError("call reset() before push_object()")
        velocity = np.asarray(velocity_mm_s, dtype=np.float64).reshape(3) / 1000.0
        self.world.client.resetBaseVelocity(self._object, velocity.tolist(), [0.0, 0.0, 0.0])

    def render_tactile(self, size_px: int | None = None) -> np.ndarray:
        """uint8 (H, W) TacTip image at the sensor's current pose (default size: ``config.tactip``)."""
        size_px = self.config.tactip.image_size_px if size_px is None else size_px
        if size_px not in self._tactips:
            self._tactips[size_px] = TacTip(self.world, replace(self.config.tactip, image_size_px=size_px))
        return self._tactips[size_px].render(self.sensor_pose())

    # -- lifetime -------------------------------------------------------------------------------------------

    def close(self) -> None:
        if self._world is not None:
            self._world.close()
            self._world = None


def _interpolate(T_start: np.ndarray, T_end: np.ndarray, fractions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses between two transforms (mm): positions (n, 3) in m, linearly, and quaternions (n, 4) xyzw, by slerp."""
    positions_m = (T_start[:3, 3] + fractions[:, None] * (T_end[:3, 3] - T_start[:3, 3])) / 1000.0
    q0, q1 = rotation_to_quaternion_xyzw(T_start[:3, :3]), rotation_to_quaternion_xyzw(T_end[:3, :3])
    cos = float(np.dot(q0, q1))
    if cos < 0.0:  # the shorter way round
        q1, cos = -q1, -cos
    angle = np.arccos(min(cos, 1.0))
    if angle < 1e-9:
        quaternions = np.tile(q1, (len(fractions), 1))
    else:
        quaternions = (np.sin((1.0 - fractions) * angle)[:, None] * q0
                       + np.sin(fractions * angle)[:, None] * q1) / np.sin(angle)
    return positions_m, quaternions


# Plain-numpy quaternion helpers (xyzw, like PyBullet): scipy's Rotation costs ~0.1 ms a call, too slow for the
# drive loop, which runs twice per physics step.

def _quaternion_multiply(a, b) -> np.ndarray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def _quaternion_conjugate(q) -> tuple[float, float, float, float]:
    return (-q[0], -q[1], -q[2], q[3])


def _quaternion_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle, rad) of a unit quaternion, the short way round."""
    if q[3] < 0.0:
        q = -q
    sin_half = float(np.linalg.norm(q[:3]))
    if sin_half < 1e-12:
        return 2.0 * q[:3]
    return q[:3] * (2.0 * np.arctan2(sin_half, q[3]) / sin_half)
