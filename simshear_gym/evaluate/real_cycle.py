"""Compute per control cycle of the real path, on this CPU.

``simshear evaluate real-cycle`` times what the rollout does every control period, on real raw camera frames
(``tactip331_raw``: 640x480 frames of the 331-pin TacTip) and against the MG400 emulator in a separate process
over loopback TCP (the robot controller is separate hardware, so its work is not counted here, but the round trip
of the command and its reply is):

1. ``preprocess``: the raw frame -> 128 px binary tactile image (:func:`~simshear_gym.real.camera.preprocess`)
   -> ``--image-size`` (:func:`~simshear_gym.real.env.tactile_from_frame`);
2. ``controller``: :class:`~simshear_gym.control.servo.ServoController` - GDNN reading, Bayesian filter, PI law;
3. ``command``: the action -> flange target (:func:`~simshear_gym.real.env.move_to_flange_target`), the safety
   checks, formatting ``ServoP(...)``, sending it and waiting for the emulator's reply (``MG400Client.servo_p``).

Cycles run back to back (no pacing). The frames cycle through the 100 recorded contacts, which are unrelated to
each other, so the command of each cycle is the action applied to the fixed start pose (the same computation as
the env's, without the arm drifting away over hundreds of cycles). The GDNN alone is timed in a separate loop for
the breakdown. Writes ``results/real_cycle.json`` with the command that produced it.
"""

from __future__ import annotations

import argparse
import multiprocessing
import time
from pathlib import Path

import numpy as np

from simshear_gym.evaluate.records import write_record
from simshear_gym.machine import machine_info

START_POSE_MM_DEG = (300.0, 0.0, 0.0, 0.0)


def _emulator_process(connection, stop) -> None:
    """Child process: an MG400 emulator on ephemeral loopback ports until ``stop`` is set."""
    from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator

    with MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0)) as emulator:
        connection.send((emulator.dashboard_port, emulator.motion_port, emulator.feedback_port))
        stop.wait(3600.0)


def load_raw_frames(root: Path) -> list[np.ndarray]:
    """The raw camera frames of ``tactip331_raw/images`` (BGR uint8), in natural order."""
    from simshear_gym.real.camera import CameraSource

    folder = root / "tactip331_raw" / "images"
    if not folder.is_dir():
        raise FileNotFoundError(f"raw TacTip frames not found: {folder} (resolved {folder.resolve()}) is missing")
    with CameraSource(folder) as source:
        return list(source)


def _stats(values_ms: list[float]) -> dict[str, float]:
    array = np.asarray(values_ms)
    return {"median_ms": round(float(np.median(array)), 3), "p95_ms": round(float(np.percentile(array, 95)), 3),
            "max_ms": round(float(array.max()), 3)}


def measure(frames: list[np.ndarray], ports: tuple[int, int, int], cycles: int, warmup: int, image_size_px: int,
            posenet: str | None) -> dict:
    """Run ``warmup`` + ``cycles`` cycles against the emulator at ``ports``; per-stage times in ms."""
    from simshear_gym.contract import ActionScale, TacTipMount
    from simshear_gym.control.estimator import EstimatorConfig
    from simshear_gym.control.servo import ServoController
    from simshear_gym.real.camera import default_config
    from simshear_gym.real.env import move_to_flange_target, tactile_from_frame
    from simshear_gym.real.mg400_client import MG400Client, MG400ClientConfig
    from simshear_gym.real.safety import SafetyConfig, SafetyLayer

    scale, mount, preprocess_config = ActionScale(), TacTipMount(), default_config()
    period_s = 0.1
    controller = ServoController(4.0, scale, estimator=EstimatorConfig(posenet=posenet))
    client = MG400Client(MG400ClientConfig(host="127.0.0.1", dashboard_port=ports[0], motion_port=ports[1],
                                           feedback_port=ports[2]), SafetyLayer(SafetyConfig())).connect()
    times: dict[str, list[float]] = {"preprocess": [], "controller": [], "command": [], "total": []}
    try:
        client.enable_robot()
        client.mov_j(*START_POSE_MM_DEG)
        client.sync()
        client.reset_reference()
        controller.reset()
        for index in range(warmup + cycles):
            frame = frames[index % len(frames)]
            t0 = time.perf_counter()
            tactile = tactile_from_frame(frame, preprocess_config, image_size_px)
            t1 = time.perf_counter()
            action = controller({"tactile": tactile[None]})
            t2 = time.perf_counter()
            target = move_to_flange_target(START_POSE_MM_DEG, action.astype(np.float64) * scale.as_array(), mount)
            client.servo_p(*target, t_s=period_s + 0.02)
            t3 = time.perf_counter()
            if index >= warmup:
                for name, start, end in (("preprocess", t0, t1), ("controller", t1, t2), ("command", t2, t3),
                                         ("total", t0, t3)):
                    times[name].append(1000.0 * (end - start))
        sent = len(times["total"]) + warmup
        gdnn_ms = []
        for index in range(cycles):
            tactile = tactile_from_frame(frames[index % len(frames)], preprocess_config, image_size_px)
            start = time.perf_counter()
            controller.estimator.read(tactile)
            gdnn_ms.append(1000.0 * (time.perf_counter() - start))
    finally:
        client.close()
    result = {name: _stats(values) for name, values in times.items()}
    result["gdnn_alone"] = _stats(gdnn_ms)
    result["servo_p_commands_sent"] = sent
    result["gdnn_input_px"] = int(controller.estimator.model.config.image_size_px)
    return result


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default=None, help="data root holding tactip331_raw/ (default: SIMSHEAR_DATA "
                                                     "or ../shared/data)")
    parser.add_argument("--cycles", type=int, default=300, help="timed cycles (default 300)")
    parser.add_argument("--warmup", type=int, default=20, help="untimed cycles first (default 20)")
    parser.add_argument("--image-size", type=int, default=128, choices=(64, 128), help="tactile observation size")
    parser.add_argument("--posenet", default=None, help="GDNN weights (default: the shipped surface GDNN)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--out", type=Path, default=Path("results"),
                        help="results directory for real_cycle.json (default results)")


def run(args: argparse.Namespace) -> int:
    if args.cycles < 10 or args.warmup < 0:  # before torch: an option error comes at once
        raise ValueError(f"--cycles must be >= 10 and --warmup >= 0, got {args.cycles}, {args.warmup}")
    import torch

    from simshear_gym.data.paths import data_root

    torch.set_num_threads(args.threads)
    root = data_root(args.data)
    frames = load_raw_frames(root)
    context = multiprocessing.get_context("spawn")
    receive, send = context.Pipe(duplex=False)
    stop = context.Event()
    emulator = context.Process(target=_emulator_process, args=(send, stop), name="mg400-emulator", daemon=True)
    emulator.start()
    try:
        if not receive.poll(60.0):
            raise RuntimeError("the MG400 emulator process did not start within 60 s")
        ports = receive.recv()
        result = measure(frames, ports, args.cycles, args.warmup, args.image_size, args.posenet)
    finally:
        stop.set()
        emulator.join(timeout=10.0)
        if emulator.is_alive():
            emulator.terminate()
    payload = {
        "machine": {**machine_info(),
                    "torch_threads": args.threads},
        "frames": f"{len(frames)} raw 640x480 frames of tactip331_raw, cycled",
        "posenet": args.posenet or "shipped surface GDNN",
        "image_size_px": args.image_size,
        "cycles": args.cycles,
        "stages": {key: result[key] for key in ("preprocess", "controller", "command", "total")},
        "gdnn_alone": result["gdnn_alone"],
        "gdnn_input_px": result["gdnn_input_px"],
        "servo_p_commands_sent": result["servo_p_commands_sent"],
        "notes": "emulator in a separate process over loopback TCP; cycles back to back; 'controller' = GDNN + "
                 "Bayesian filter + PI law; 'command' = target, safety checks, ServoP formatting, send and reply",
    }
    path = write_record("simshear evaluate real-cycle", add_arguments, args, args.out / "real_cycle.json", payload)
    for name, stats in payload["stages"].items():
        print(f"{name:10s} median {stats['median_ms']:7.3f} ms   p95 {stats['p95_ms']:7.3f} ms")
    print(f"{'GDNN alone':10s} median {payload['gdnn_alone']['median_ms']:7.3f} ms")
    print(f"wrote {path}")
    return 0
