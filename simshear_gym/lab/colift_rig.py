"""The rehearsal rig for co-lift: the co-lift scene's object between the two emulated arms.

:class:`CoLiftRig` is a :class:`~simshear_gym.lab.rig.RehearsalRig` (two loopback MG400 emulators, faults, audit)
in the co-lift layout (:mod:`simshear_gym.lab.colift`: the leader holds the upright plate, the follower the
horizontal TacTip, 750 mm apart) whose camera, :class:`CoLiftCamera`, sees the object the two arms hold:

* **On its support** (until :meth:`CoLiftCamera.release`, the squeeze reached): the object rests against the plate's
  face where the co-lift scene places it at reset, carried with the plate; the follower's approach and squeeze
  press the dome into it (penetration along the grip axis, no shear).
* **Carried** (from the release until :meth:`CoLiftCamera.set_down`): the co-lift scene
  (:class:`~simshear_gym.sim.colift_scene.CoLiftScene`, the physics of ``SimShearCoLift-v0``) is reset with the
  squeeze the follower reached and then stepped, one control period of physics per frame, from the plate and the
  sensor where the two emulators' own states put them; nothing but friction holds the object, so it slips or falls
  when the follower lags or lets go.

Each frame is made as the co-lift env makes its images: the TacTip renders the object's penetration into the
undeformed dome (a visual copy of the object in the camera's own world, at the physics object's pose), conditioned
on the skin's shear from the scene, translated by the shipped shPix2pix and embedded in a camera frame
(:class:`~simshear_gym.lab.rig.RigCamera`). Ground truth per frame (:class:`CoLiftTruth`): the true contact error
(the sensor against the point of the plate it stood on at the mark, carried with the plate), the penetration,
contact, and once carried the drop, the object's slip on the plate and its depth in the dome. Faults besides the
rig's: :meth:`CoLiftCamera.knock` (the object is knocked out of the grip).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from simshear_gym.contract import HorizontalTacTipMount
from simshear_gym.lab.colift_layout import (
    COLIFT_LEADER_IN_FOLLOWER_MM_DEG,
    COLIFT_LEADER_START_POSE_MM_DEG,
    ObjectFace,
)
from simshear_gym.lab.frames import BaseToBase
from simshear_gym.lab.rig import RehearsalRig, RigCamera, RigConfig, RigTruth
from simshear_gym.real.camera import PreprocessConfig
from simshear_gym.robots.mg400.frames import pose_to_T_base_flange
from simshear_gym.sim.colift_scene import CoLiftScene, CoLiftSceneConfig
from simshear_gym.sim.objects import OBJECTS, spawn_object
from simshear_gym.sim.tactip import TacTipConfig
from simshear_gym.transforms import invert, matrix_to_pybullet_fast, pose_from_matrix_fast

_PHYSICS_RATE_HZ = 240.0  # the co-lift env's


@dataclass(frozen=True)
class CoLiftTruth(RigTruth):
    """:class:`~simshear_gym.lab.rig.RigTruth` (``target_mm`` / ``contact_error_mm`` carried with the plate) and the
    object: ``carried`` (off its support, the physics stepping), ``dropped`` (the scene's drop: slipped 20 mm from its
    place on the plate, or touching neither gripper), ``object_slip_mm`` (its drift on the plate since the grasp)."""

    carried: bool = False
    dropped: bool = False
    object_slip_mm: float = 0.0


class CoLiftCamera(RigCamera):
    """The follower's TacTip on the co-lift object (module docstring).

    Args:
        follower_pose, leader_pose: the arms' flange poses ``(x, y, z mm, R deg)`` in their base frames.
        T_follower_leader: the leader's base in the follower's frame (the rig's truth).
        face: the object and the plate on the leader's flange.
        control_period_s: physics time per frame (one control period).
        mount, raw_frame_layout, noise_seed: as :class:`~simshear_gym.lab.rig.RigCamera`.
    """

    def __init__(self, follower_pose: Callable[[], object], leader_pose: Callable[[], object],
                 T_follower_leader: np.ndarray, face: ObjectFace = ObjectFace(), control_period_s: float = 0.1,
                 mount: HorizontalTacTipMount = HorizontalTacTipMount(),
                 raw_frame_layout: PreprocessConfig | None = None, noise_seed: int = 0) -> None:
        T_flange_plate = face.T_flange_plate()

        def T_follower_plate() -> np.ndarray:
            return T_follower_leader @ pose_to_T_base_flange(np.asarray(leader_pose(), dtype=np.float64)[:4]) \
                @ T_flange_plate

        substeps = max(1, round(_PHYSICS_RATE_HZ * control_period_s))
        self.scene_config = CoLiftSceneConfig(object_name=face.object_name, physics_rate_hz=substeps / control_period_s,
                                              substeps=substeps, tactip=TacTipConfig(image_size_px=128))
        self.spec = self.scene_config.object
        self.scene = CoLiftScene(self.scene_config)
        self._face = face
        self._T_plate_face = invert(T_flange_plate) @ face.T_flange_face()
        # where the scene puts the object against the plate (its reset's placement, before any physics step)
        with CoLiftScene(replace(self.scene_config, settle_s=0.0)) as probe:
            T_plate = T_follower_plate()
            probe.reset(T_plate, 0.0)
            self._T_plate_object = invert(T_plate) @ probe.object_pose()
        self.carried = False
        self._T_plate = self._T_sensor = None
        super().__init__(follower_pose, T_follower_plate, (*face.size_mm, face.thickness_mm), mount, raw_frame_layout,
                         noise_seed)
        self.name = "rehearsal rig camera (co-lift)"

    # -- the object's support --------------------------------------------------------------------------------------

    def release(self) -> None:
        """The object leaves its support: the physics carries it from the squeeze the follower holds now (its
        weight and, for the soft brain, its own compliance now on the grip). Idempotent."""
        with self._lock:
            if self.carried or self._T_plate is None:
                return
            squeeze_mm = -float((invert(self._T_plate @ self._T_plate_face) @ self._T_sensor)[2, 3])
            squeeze_mm = float(np.clip(squeeze_mm, 0.0, 0.9 * self.scene_config.tactip.dome_radius_mm))
            self.scene.reset(self._T_plate, squeeze_mm)
            self.scene.step(self._T_plate, self._T_sensor)  # from the scene's grip to where the follower is
            self.carried = True

    def set_down(self) -> None:
        """The object is back on its support (held where it is on the plate; the physics stops)."""
        with self._lock:
            if self.carried:
                self._T_plate_object = invert(self.scene.plate_pose()) @ self.scene.object_pose()
                self.carried = False

    def knock(self, velocity_mm_s=(0.0, 0.0, -500.0)) -> None:
        """Fault: the carried object is knocked out of the grip (its velocity set, follower's base frame, mm/s)."""
        with self._lock:
            if not self.carried:
                raise RuntimeError("CoLiftCamera.knock(): the object is on its support, not carried")
            self.scene.push_object(velocity_mm_s)

    # -- RigCamera's hooks -----------------------------------------------------------------------------------------

    def _spawn(self, T_base_plate: np.ndarray) -> int:
        return spawn_object(self.world, self.spec, T_base_plate @ self._T_plate_object)

    def _touch(self, T_base_sensor: np.ndarray) -> tuple[np.ndarray, float, bool, np.ndarray]:
        T_plate = np.asarray(self._T_follower_face(), dtype=np.float64)
        self._T_plate, self._T_sensor = T_plate, T_base_sensor
        if self.carried:
            self.scene.step(T_plate, T_base_sensor)
            T_object = self.scene.object_pose()
            penetration_mm = self.scene.contact_depth_mm()
            in_contact = penetration_mm > 0.0
            shear = self.scene.shear_sensor()
        else:
            # on the support: the skin shears over the object's face as over the tracking rig's plate
            T_object = T_plate @ self._T_plate_object
            T_face_sensor = invert(T_plate @ self._T_plate_face) @ T_base_sensor
            penetration_mm = -float(T_face_sensor[2, 3])
            half = self._face.half_extents_mm
            in_contact = bool(penetration_mm > 0.0 and abs(T_face_sensor[0, 3]) <= half[0]
                              and abs(T_face_sensor[1, 3]) <= half[1])
            shear = self._tracker.update(pose_from_matrix_fast(self._T_work_face @ T_face_sensor), in_contact)
        self.world.client.resetBasePositionAndOrientation(self._body, *matrix_to_pybullet_fast(T_object))
        return T_plate, penetration_mm, in_contact, shear

    def _truth(self, time_s: float, flange: np.ndarray, sensor_mm: np.ndarray, target_mm: np.ndarray | None,
               penetration_mm: float, in_contact: bool, contact_error_mm: float) -> CoLiftTruth:
        dropped = self.carried and self.scene.dropped()
        slip_mm = self.scene.object_slip_mm() if self.carried else 0.0
        return CoLiftTruth(time_s, flange, sensor_mm, target_mm, penetration_mm, in_contact and not dropped,
                           contact_error_mm, self.carried, dropped, slip_mm)

    def close(self) -> None:
        super().close()
        self.scene.close()


@dataclass(frozen=True)
class CoLiftRigConfig(RigConfig):
    """The co-lift rig's layout: :class:`~simshear_gym.lab.rig.RigConfig`'s (``plate`` the object's
    :class:`ObjectFace`, ``hover_mm`` the dome apex's distance from it) in the co-lift layout, and:

    Attributes:
        object_name: the object the arms carry (one of the co-lift env's); sets ``plate`` when that is None.
        control_period_s: physics time per camera frame, s.
    """

    leader_in_follower: BaseToBase = BaseToBase(*COLIFT_LEADER_IN_FOLLOWER_MM_DEG)
    leader_start_pose_mm_deg: tuple[float, float, float, float] = COLIFT_LEADER_START_POSE_MM_DEG
    plate: Any = None
    mount: HorizontalTacTipMount = HorizontalTacTipMount()
    object_name: str = "prism"
    control_period_s: float = 0.1

    def __post_init__(self) -> None:
        if self.object_name not in OBJECTS:
            raise ValueError(f"CoLiftRigConfig.object_name must be one of {tuple(OBJECTS)}, got {self.object_name!r}")
        if self.plate is None:
            object.__setattr__(self, "plate", ObjectFace(self.object_name))
        super().__post_init__()

    @classmethod
    def for_run(cls, config, **changes) -> CoLiftRigConfig:
        """The rig laid out as a co-lift run's ``config`` has it (its object and control period too)."""
        return super().for_run(config, object_name=config.object_name,
                               control_period_s=config.real_env.control_period_s, **changes)

    @property
    def face(self) -> ObjectFace:
        return self.plate


class CoLiftRig(RehearsalRig):
    """Two loopback MG400 emulators in the co-lift layout and the co-lift camera between them."""

    config: CoLiftRigConfig

    def __init__(self, config: CoLiftRigConfig = CoLiftRigConfig()) -> None:
        super().__init__(config)

    def new_camera(self) -> CoLiftCamera:
        """A fresh co-lift camera (the object back on its support, a fresh scene); the old one is closed."""
        if self.camera is not None:
            self.camera.close()
        cfg = self.config
        leader, follower = self.leader, self.follower
        self.camera = CoLiftCamera(lambda: follower.pose, lambda: leader.pose,
                                   cfg.leader_in_follower.T_follower_leader(), cfg.plate, cfg.control_period_s,
                                   cfg.mount, cfg.preprocess, cfg.camera_seed)
        return self.camera
