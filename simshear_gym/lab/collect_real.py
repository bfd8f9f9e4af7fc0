"""Record a sensor's tactile data set with the arm, in the package's data format, from a ``[collect]`` protocol
(:mod:`simshear_gym.lab.collect_protocol`); the command is ``simshear collect-real``
(:mod:`simshear_gym.pipelines.collect_real`).

1. Touch-off: the sensor hovers above the work origin and steps down (``touch_step_mm``) until its image differs
   from the one it showed in the air (``touch_threshold``: mean absolute grey change); the face's height in the base
   frame is where the contact began, and every row's depth is measured from it.
2. Per row (in the protocol's order): the arm's path of :meth:`CollectProtocol.row_waypoints` through the safe
   client (every move passes the safety layer), a wait until the fed-back pose is the row's pose and the queue is
   empty, the settle time, ``frames_per_capture`` camera frames averaged and preprocessed (the same preprocessing
   as the real loop), the image written atomically, then the row appended to ``targets.csv`` atomically. So a run
   killed at any moment leaves whole rows only, and the rerun (same command) continues at the next row: no
   duplicate, no gap.
3. Ctrl-C (or any error) lifts the sensor clear above the face before the command stops.

Output (``DIR``): ``images/image_N.png``, ``targets.csv`` (``sensor_image``, ``pose_1..6``, ``move_1..6`` in the
simulation's frame and units, ``kind``, ``robot_time_s``), ``meta.json`` (the protocol, the touch-off, the
config), and ``config_stub.toml``: a config for ``simshear pipeline check`` / ``run`` that reads the set as it is
(identity frame, every label in mm and deg, the stimulus geometry copied from the config).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd

from simshear_gym.data.labels import MOVE_COLUMNS, POSE_COLUMNS, wrap_deg
from simshear_gym.data.tactile_set import IMAGE_COLUMN, image_name
from simshear_gym.io import atomic_write
from simshear_gym.lab.collect_protocol import CollectProtocol
from simshear_gym.real.mg400_client import wait_at_pose

TARGETS = "targets.csv"
META = "meta.json"
STUB = "config_stub.toml"


class CollectError(RuntimeError):
    """The collection cannot go on (the arm did not arrive, the touch-off found no face, another protocol's rows
    in the output folder)."""


@dataclass(frozen=True)
class TouchOff:
    """Where the face is: its height in the base frame (the sensor's apex at first contact), the flange height
    then, and the image change that showed it."""

    face_z_base_mm: float
    flange_z_base_mm: float
    change_grey: float


def average_frame(camera, frames: int) -> np.ndarray:
    """``frames`` camera frames, averaged (uint8)."""
    stack = np.stack([np.asarray(camera.read(), dtype=np.float32) for _ in range(frames)])
    return np.clip(np.rint(stack.mean(axis=0)), 0, 255).astype(np.uint8)


def wait_arrived(client, pose: np.ndarray, timeout_s: float = 10.0, tolerance: float = 0.05,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
    """Wait until the fed-back pose is ``pose`` (mm, deg) and no queued move runs; raise ``CollectError``."""
    reached = wait_at_pose(client, pose, tolerance, timeout_s, 0.005, clock, sleep)
    if reached is not None:
        raise CollectError(f"the arm stopped at {reached.round(3).tolist()} instead of "
                           f"{np.round(pose, 3).tolist()}")


def move_to(client, pose: np.ndarray) -> None:
    """MovL to ``pose`` through the safe client, then wait for it; a turn larger than the safety layer lets one
    queued move make is made first, in place, in equal turns (the sensor is in the air then: a row's moves into
    and along the contact turn a few degrees at most, :meth:`CollectProtocol.check_reach`)."""
    pose = np.asarray(pose, dtype=np.float64)
    limit_deg = 0.9 * float(client.safety.config.max_move_deg)
    start = np.asarray(client.measured_pose(), dtype=np.float64)[:4]
    turn_deg = float(wrap_deg(pose[3] - start[3]))
    pieces = int(math.ceil(abs(turn_deg) / limit_deg))
    targets = []
    if pieces > 1:
        targets = [np.array([*start[:3], start[3] + turn_deg * piece / pieces]) for piece in range(1, pieces + 1)]
    for target in [*targets, pose]:
        client.mov_l(*(float(v) for v in target))
        client.sync()
        wait_arrived(client, target)


def apex_z(protocol: CollectProtocol, flange_pose: np.ndarray) -> float:
    """Base-frame height of the sensor's apex under a level flange pose."""
    T_base_flange = np.eye(4)
    T_base_flange[2, 3] = float(flange_pose[2])
    return float((T_base_flange @ protocol.mount.T_flange_sensor())[2, 3])


def touch_off(client, camera, protocol: CollectProtocol, preprocess: Callable[[np.ndarray], np.ndarray],
              step_mm: float = 0.1, threshold: float = 3.0, fit_steps: int = 3, max_travel_mm: float = 20.0
              ) -> TouchOff:
    """Step the sensor down from above the work origin until its image changes by more than ``threshold`` grey
    levels (mean absolute change from the image in the air), then ``fit_steps`` steps more; the face lies where a
    line through those points' (height, change) reaches no change (an image changes with the indentation from its
    onset, so the first detectable change lies past the face; the line finds the onset)."""
    air = np.array([0.0, 0.0, protocol.surface_depth_mm - protocol.hover_mm, 0.0, 0.0, 0.0])
    start = protocol.flange_pose(air, protocol.T_base_work())
    move_to(client, start)
    reference = preprocess(average_frame(camera, protocol.frames_per_capture)).astype(np.float32)
    heights, changes = [], []
    for index in range(1, int(math.ceil(max_travel_mm / step_mm)) + 1):
        target = start.copy()
        target[2] -= index * step_mm
        move_to(client, target)
        change = float(np.abs(preprocess(average_frame(camera, protocol.frames_per_capture)) - reference).mean())
        if change > threshold or heights:
            heights.append(float(target[2]))
            changes.append(change)
        if len(heights) > fit_steps:
            break
    move_to(client, start)
    if len(heights) <= fit_steps:
        raise CollectError(f"touch-off: no contact within {max_travel_mm:g} mm below the hover point (image change "
                           f"stayed under {threshold:g} grey levels): check work_origin_base_mm z and the camera")
    slope, intercept = np.polyfit(changes, heights, 1)  # flange height as a line in the change: height at 0
    onset = start.copy()
    onset[2] = float(intercept)
    return TouchOff(round(apex_z(protocol, onset), 4), round(float(intercept), 4), round(changes[0], 3))


def _done_rows(out_dir: Path, protocol: CollectProtocol) -> tuple[pd.DataFrame | None, dict | None]:
    """The rows already recorded in ``out_dir`` (None: none) and its meta; refuses another protocol's rows."""
    targets, meta = out_dir / TARGETS, out_dir / META
    if not targets.is_file():
        return None, None
    record = json.loads(meta.read_text()) if meta.is_file() else {}
    if record.get("protocol") != _protocol_record(protocol):
        raise CollectError(f"{out_dir}: holds rows of another [collect] protocol (meta.json); give a new --out or "
                           "the config that made them")
    return pd.read_csv(targets), record


def _protocol_record(protocol: CollectProtocol) -> dict:
    return json.loads(json.dumps(asdict(protocol), default=list))


def collect(protocol: CollectProtocol, client, camera, out_dir: str | Path,
            preprocess: Callable[[np.ndarray], np.ndarray], config_record: dict | None = None,
            clock: Callable[[], float] = time.monotonic, progress: Callable[[int, int, float], None] | None = None,
            stop_after_rows: int | None = None) -> dict[str, Any]:
    """Record the protocol's rows into ``out_dir`` (resuming there; see the module docstring); returns a summary.

    ``client``: a connected, enabled :class:`~simshear_gym.real.mg400_client.MG400Client`; ``camera``: a frame
    source; ``preprocess``: camera frame -> tactile image; ``progress(done, total, row_s)`` after each row;
    ``stop_after_rows``: stop after this many new rows (a test's stand-in for a kill)."""
    out_dir = Path(out_dir)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    for leftover in (out_dir / "images").glob(".*.tmp*"):  # a write a kill cut short: its row is recorded again
        leftover.unlink()
    done, meta = _done_rows(out_dir, protocol)
    if meta is None:
        touch = touch_off(client, camera, protocol, preprocess)
        meta = {"protocol": _protocol_record(protocol), "touch_off": asdict(touch), "config": config_record or {}}
        atomic_write(out_dir / META, lambda path: Path(path).write_text(json.dumps(meta, indent=2)))
    touch = TouchOff(**meta["touch_off"])
    rows, waypoints, planned_s = protocol.plan(touch.face_z_base_mm)
    table = done if done is not None else pd.DataFrame(columns=[IMAGE_COLUMN, *POSE_COLUMNS, *MOVE_COLUMNS, "kind",
                                                                "robot_time_s"])
    start_row = len(table)
    recorded = []
    try:
        for index in range(start_row, len(rows)):
            if stop_after_rows is not None and index - start_row >= stop_after_rows:
                break
            started = clock()
            points = waypoints[index]
            move_to(client, points["hover"])
            move_to(client, points["touch"])
            move_to(client, points["pose"])
            time.sleep(protocol.settle_s)
            image = preprocess(average_frame(camera, protocol.frames_per_capture))
            name = image_name(index)
            atomic_write(out_dir / "images" / name, lambda path, image=image: _write_png(path, image), suffix=".png")
            row = rows.iloc[index]
            elapsed_s = clock() - started
            entry = {IMAGE_COLUMN: name, **{c: float(row[c]) for c in POSE_COLUMNS + MOVE_COLUMNS},
                     "kind": row["kind"], "robot_time_s": round(elapsed_s, 4)}
            table = pd.concat([table, pd.DataFrame([entry])], ignore_index=True) if len(table) else pd.DataFrame(
                [entry])
            atomic_write(out_dir / TARGETS, lambda path, table=table: table.to_csv(path, index=False))
            recorded.append(elapsed_s)
            if progress is not None:
                progress(len(table), len(rows), elapsed_s)
    finally:
        _lift_clear(client, protocol, touch)
    return {"rows": len(table), "total": len(rows), "new_rows": len(recorded), "resumed_at": start_row,
            "touch_off": asdict(touch), "planned_row_s_mean": round(float(planned_s.mean()), 4),
            "row_s_mean": round(float(np.mean(recorded)), 4) if recorded else None,
            "complete": len(table) == len(rows)}


def _write_png(path: str, image: np.ndarray) -> None:
    if not cv2.imwrite(path, image):
        raise OSError(f"{path}: could not be written")


def _lift_clear(client, protocol: CollectProtocol, touch: TouchOff) -> None:
    """Lift the sensor straight up to the hover height above the face, from wherever it is."""
    try:
        pose, _ = client.measured_state()
    except Exception:  # noqa: BLE001 - no feedback: nothing safe to command
        return
    pose = np.asarray(pose, dtype=np.float64)[:4]
    hover_z = pose[2] + (touch.face_z_base_mm + protocol.hover_mm - apex_z(protocol, pose))
    if pose[2] < hover_z - 1e-6:
        target = pose.copy()
        target[2] = hover_z
        client.reset_reference()
        move_to(client, target)


def config_stub(name: str, protocol: CollectProtocol, config_text_tables: dict[str, dict], out_dir: Path,
                rows: pd.DataFrame) -> str:
    """A ``pipeline check`` / ``run`` config that reads the collected set as it is: identity frame, labels in
    mm and deg by their canonical columns, a seeded 20 % validation split; ``config_text_tables``: the source
    config's ``sensor`` and ``replay`` tables."""
    def table(values: dict) -> str:
        return "\n".join(f"{key} = {json.dumps(value)}" for key, value in values.items())

    kind = "shear" if (rows["kind"] == "shear").any() else "tap"
    lines = [f'name = "{name}"', f'description = "collected by simshear collect-real ({protocol.rows} rows)"', "",
             "[sensor]", table(config_text_tables.get("sensor", {})), "", "[replay]",
             table(config_text_tables.get("replay", {})), "", "[frame]", 'axes = ["x", "y", "z"]', "",
             f"[datasets.{protocol.stimulus}_{kind}]", f'contact = "{protocol.stimulus}"', f'kind = "{kind}"',
             f'image_column = "{IMAGE_COLUMN}"', "val_fraction = 0.2",
             f'files = [{{ csv = "{out_dir / TARGETS}", images = "{out_dir / "images"}" }}]', "",
             f"[datasets.{protocol.stimulus}_{kind}.labels]"]
    names = ("pose_x", "pose_y", "pose_z", "pose_rx", "pose_ry", "pose_rz",
             "move_x", "move_y", "move_z", "move_rx", "move_ry", "move_rz")
    for variable, column in zip(names, POSE_COLUMNS + MOVE_COLUMNS):
        values = rows[column].to_numpy(np.float64)
        if np.ptp(values) > 1e-9:
            unit = "deg" if variable.split("_")[1].startswith("r") else "mm"
            lines.append(f'{variable} = {{ column = "{column}", unit = "{unit}" }}')
        else:
            lines.append(f"{variable} = {{ value = {float(values[0])!r} }}")
    return "\n".join(lines) + "\n"


def plan_text(protocol: CollectProtocol, times_s: np.ndarray) -> str:
    rows = protocol.draw_rows()
    shear = int((rows["kind"] == "shear").sum())
    ranges = ", ".join(f"{k} [{lo:g}, {hi:g}]" for k, (lo, hi) in protocol.ranges.items())
    return (f"[collect] {protocol.rows} {protocol.stimulus} rows ({shear} shear, {protocol.rows - shear} tap), seed "
            f"{protocol.seed}: {ranges}\n"
            f"robot time per row {times_s.mean():.2f} s mean, {times_s.max():.2f} s max (trapezoidal moves at "
            f"{protocol.speed_mm_s:g} mm/s, {protocol.acceleration_mm_s2:g} mm/s^2; settle {protocol.settle_s:g} s, "
            f"{protocol.frames_per_capture} frame(s)); {times_s.sum() / 60.0:.1f} min in all")


def rehearsal_camera(protocol: CollectProtocol, geometry, follower_pose: Callable[[], object]):
    """A rig camera (:class:`~simshear_gym.lab.rig.RigCamera`) rendering the protocol's stimulus where the config
    says it lies (the work frame's place, ``geometry``: the config's ``[replay]``), seen from the flange pose that
    ``follower_pose`` returns (an emulator's state, or an arm's feedback), in a raw camera frame."""
    from simshear_gym.lab.rig import RigCamera
    from simshear_gym.real.camera import default_config
    from simshear_gym.sim.stimuli import make_stimulus

    stimulus = make_stimulus(protocol.stimulus)
    T_base_stimulus = protocol.T_base_work() @ geometry.T_work_stimulus()
    return RigCamera(follower_pose, lambda: T_base_stimulus, stimulus.size_mm, protocol.mount, default_config(),
                     contact=protocol.stimulus, stimulus=stimulus)


def rehearsal_emulator(protocol: CollectProtocol):
    """A loopback MG400 emulator (not started) whose sensor stands 5 mm above the protocol's hover height over the
    work origin: where a rehearsed collection starts."""
    from simshear_gym.lab.rig import loopback_emulator

    air = np.array([0.0, 0.0, protocol.surface_depth_mm - protocol.hover_mm - 5.0, 0.0, 0.0, 0.0])
    return loopback_emulator(protocol.flange_pose(air, protocol.T_base_work()))


class Rehearsal:
    """An emulated MG400 (loopback) and a rig camera rendering the protocol's stimulus where the config says it lies
    (:func:`rehearsal_camera`; a context manager): the whole collection runs on it, with no hardware."""

    def __init__(self, protocol: CollectProtocol, geometry=None) -> None:
        from simshear_gym.sim.replay import ReplayGeometry

        self.protocol = protocol
        self.geometry = ReplayGeometry(surface_depth_mm=protocol.surface_depth_mm) if geometry is None else geometry
        self.emulator = None
        self.camera = None

    def __enter__(self) -> Rehearsal:
        self.emulator = rehearsal_emulator(self.protocol)
        self.emulator.start()
        emulator = self.emulator
        self.camera = rehearsal_camera(self.protocol, self.geometry, lambda: emulator.pose)
        return self

    def __exit__(self, *exc_info: object) -> None:
        if self.camera is not None:
            self.camera.close()
        if self.emulator is not None:
            self.emulator.stop()

    @property
    def endpoint(self):
        from simshear_gym.lab.endpoints import ArmEndpoint

        return ArmEndpoint("127.0.0.1", self.emulator.dashboard_port, self.emulator.motion_port,
                           self.emulator.feedback_port)


def connect(endpoint, safety):
    """A connected, enabled safe client for the arm at ``endpoint`` (refuses an arm in error mode)."""
    from simshear_gym.lab.experiment import _ready
    from simshear_gym.real.env import env_client
    from simshear_gym.real.mg400_client import MG400Client
    from simshear_gym.real.safety import SafetyLayer

    client = MG400Client(env_client(**asdict(endpoint), feedback_max_age_s=safety.max_feedback_age_s),
                         SafetyLayer(safety))
    client.connect()
    _ready(client, "collecting")
    return client


def check_protocol(protocol: CollectProtocol, safety) -> np.ndarray:
    """Every row's path against the arm's reach and the safety layer (before anything moves); the robot times."""
    def inside(pose: np.ndarray) -> bool:
        x, y, z, r = (float(v) for v in pose[:4])
        ranges = ((x, safety.x_range_mm), (y, safety.y_range_mm), (z, safety.z_range_mm),
                  (math.hypot(x, y), safety.radius_range_mm), (r, safety.r_range_deg))
        return all(low <= value <= high for value, (low, high) in ranges)

    _, waypoints, times = protocol.plan()
    protocol.check_reach(waypoints, inside, safety.max_move_mm, safety.max_move_deg, safety.max_speed_mm_s)
    return times
