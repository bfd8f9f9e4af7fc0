"""Bursts of individually valid motion commands against the MG400 emulator: does an arm ever move faster than the
limits?

``simshear evaluate safety-bursts --sequences 1000 --seed 0`` runs :func:`run_bursts` and writes
``results/safety_bursts.json`` (with its command line) and ``results/safety_bursts.png``.

Each sequence sends, to each of two arms at once (two emulators on their own loopback ports, each driven by its
own :class:`~simshear_gym.real.mg400_client.MG400Client` with the safe default limits, from its own thread), 3 to
12 commands drawn from a seeded generator: ``ServoP`` with ``t`` in 0.02-0.1 s, each target within
``max_step_mm`` of the one before and at most ``max_speed_mm_s`` from it over ``t`` (individually valid), and now and
then a ``MovL`` of up to 10 mm; back to back (40 %) or after a random gap of up to 40 ms. Such a burst asks the arm
for far more than one command's speed, because a servo command replaces the target and asks the arm to get there
from wherever it is in ``t``; the client must refuse (or with ``--clamp`` clamp) what would be too fast.

The audit reads **the emulators' own record** of what each arm executed
(:meth:`~simshear_gym.real.mg400_emulator.MG400Emulator.executed_motions`: every servo command accepted and every
queued move started, with its peak flange speed, R and joint rates and accelerations) and counts the motions, and
the sequences, where an arm moved faster than ``max_speed_mm_s`` / ``max_speed_deg_s`` (the acceptance figure: 0),
and, separately, accelerated faster than ``max_accel_*``. The same sequences sent as raw command strings without
the client (``--baseline-sequences``, default 200) show what the limits are up against.

The emulators run at 1000 mm/s and 400 deg/s at 100 %, the client's assumed speeds at 100 %
(``SafetyConfig.arm_*``), so the queued moves' ratios are as tight as they get.
"""

from __future__ import annotations

import argparse
import math
import socket
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simshear_gym.evaluate.figures import pyplot, save_figure
from simshear_gym.evaluate.records import write_record

READY_POSE_MM_DEG = (300.0, 0.0, 0.0, 0.0)
BOX_HALF_MM = 20.0  # targets stay within this box around the ready pose
EMULATOR_SPEEDS = dict(joint_speed_deg_s=400.0, linear_speed_mm_s=1000.0)


@dataclass(frozen=True)
class BurstConfig:
    """Settings of one burst benchmark.

    Attributes:
        sequences: sequences per arm, each sent to every arm at once.
        seed: seeds every command, gap and ``t``.
        arms: arms (emulators), each with its own client.
        commands: (fewest, most) commands per sequence.
        back_to_back_fraction: share of commands sent with no gap.
        max_gap_s: the longest random gap before a command, s.
        servo_t_range_s: (shortest, longest) ``t`` of a ServoP, s.
        mov_l_fraction: share of commands that are a MovL.
        mov_l_max_mm: the longest MovL, mm.
        clamp: the clients clamp servo targets instead of refusing them (``servo_over_limit="clamp"``).
        settle_timeout_s: how long to wait for the arms to come to rest after a sequence, s.
    """

    sequences: int = 1000
    seed: int = 0
    arms: int = 2
    commands: tuple[int, int] = (3, 12)
    back_to_back_fraction: float = 0.4
    max_gap_s: float = 0.04
    servo_t_range_s: tuple[float, float] = (0.02, 0.1)
    mov_l_fraction: float = 0.1
    mov_l_max_mm: float = 10.0
    clamp: bool = False
    settle_timeout_s: float = 3.0

    def __post_init__(self) -> None:
        if self.sequences < 1 or self.arms < 1:
            raise ValueError(f"BurstConfig needs sequences >= 1 and arms >= 1, got {self.sequences}, {self.arms}")
        low, high = self.commands
        if not 1 <= low <= high:
            raise ValueError(f"BurstConfig.commands must be (fewest, most) with 1 <= fewest <= most, got "
                             f"{self.commands!r}")
        t_low, t_high = self.servo_t_range_s
        if not 0.004 <= t_low <= t_high <= 3600.0:
            raise ValueError(f"BurstConfig.servo_t_range_s must lie in [0.004, 3600] s, got {self.servo_t_range_s!r}")
        for name in ("back_to_back_fraction", "mov_l_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"BurstConfig.{name} must be in [0, 1], got {getattr(self, name)!r}")
        for name in ("max_gap_s", "mov_l_max_mm", "settle_timeout_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"BurstConfig.{name} must be finite and >= 0, got {value!r}")


@dataclass(frozen=True)
class BurstCommand:
    """One command of a sequence: ``kind`` ServoP or MovL, the gap before it (s), the offset of its target from the
    previous target (x, y, z mm, R deg) and, for ServoP, ``t`` (s)."""

    kind: str
    gap_s: float
    offset: tuple[float, float, float, float]
    t_s: float | None


def make_sequence(config: BurstConfig, sequence: int, arm: int, max_step_mm: float, max_speed_mm_s: float,
                  max_step_deg: float, max_speed_deg_s: float) -> list[BurstCommand]:
    """The commands of one sequence for one arm: each within the per-command limits from the one before."""
    rng = np.random.default_rng([config.seed, sequence, arm])
    count = int(rng.integers(config.commands[0], config.commands[1] + 1))
    out = []
    for _ in range(count):
        gap_s = 0.0 if rng.random() < config.back_to_back_fraction else float(rng.uniform(0.0, config.max_gap_s))
        direction = rng.normal(size=3)
        direction /= max(float(np.linalg.norm(direction)), 1e-12)
        if rng.random() < config.mov_l_fraction:
            length_mm = float(rng.uniform(0.0, config.mov_l_max_mm))
            out.append(BurstCommand("MovL", gap_s, (*(direction * length_mm), 0.0), None))  # type: ignore[arg-type]
            continue
        t_s = float(rng.uniform(*config.servo_t_range_s))
        length_mm = float(rng.uniform(0.3, 1.0)) * min(max_step_mm, max_speed_mm_s * t_s) * 0.999
        r_deg = float(rng.uniform(-1.0, 1.0)) * 0.5 * min(max_step_deg, max_speed_deg_s * t_s)
        out.append(BurstCommand("ServoP", gap_s, (*(direction * length_mm), r_deg), t_s))  # type: ignore[arg-type]
    return out


def _targets(start: np.ndarray, commands: list[BurstCommand]) -> list[np.ndarray]:
    """Absolute targets: each offset from the previous target, reflected back into the box around the ready pose."""
    centre = np.array(READY_POSE_MM_DEG)
    targets, current = [], start.copy()
    for command in commands:
        offset = np.array(command.offset)
        nxt = current + offset
        outside = np.abs(nxt[:3] - centre[:3]) > BOX_HALF_MM
        offset[:3][outside] *= -1.0  # reflect: the same step length, back toward the centre
        current = current + offset
        targets.append(current.copy())
    return targets


# ----------------------------------------------------------------------------------------------------------------
# Senders: through the client, and raw (the baseline)


@dataclass
class _ArmTally:
    attempted: int = 0
    sent: int = 0
    refused: dict[str, int] | None = None
    robot_errors: int = 0
    unhandled: int = 0
    unhandled_examples: list[str] | None = None
    alarms: int = 0

    def __post_init__(self) -> None:
        self.refused = {}
        self.unhandled_examples = []


def _refusal_kind(message: str) -> str:
    for key, kind in (("stream speed", "stream_speed"), ("stream acceleration", "stream_acceleration"),
                      ("max_step", "step"), ("max_move", "jump"), ("speed of", "command_speed"),
                      ("even at 1 %", "queued_too_fast"), ("workspace", "workspace"), ("arm's limits", "reach"),
                      ("stale", "stale_feedback"), ("error mode", "error_mode")):
        if key in message:
            return kind
    return "other"


def _send_guarded(client, commands: list[BurstCommand], tally: _ArmTally) -> None:
    from simshear_gym.real.mg400_client import MG400Error
    from simshear_gym.real.safety import SafetyError

    start, _ = client.measured_state()
    for command, target in zip(commands, _targets(np.asarray(start), commands)):
        if command.gap_s > 0.0:
            time.sleep(command.gap_s)
        tally.attempted += 1
        try:
            if command.kind == "ServoP":
                client.servo_p(*target, t_s=command.t_s)
            else:
                client.mov_l(*target)
        except SafetyError as error:
            kind = _refusal_kind(str(error))
            tally.refused[kind] = tally.refused.get(kind, 0) + 1  # type: ignore[index]
            continue
        except MG400Error:
            tally.robot_errors += 1  # e.g. a ServoP while a MovL runs: the controller refuses it
            continue
        except Exception as error:  # noqa: BLE001 - counted: the benchmark reports what the client failed to handle
            tally.unhandled += 1
            tally.unhandled_examples.append(f"{type(error).__name__}: {error}")  # type: ignore[union-attr]
            continue
        tally.sent += 1


def _raw_request(sock: socket.socket, command: str) -> str:
    sock.sendall(command.encode("ascii"))
    data = b""
    while not data.endswith(b";"):
        chunk = sock.recv(4096)
        if not chunk:
            break
        data += chunk
    return data.decode("ascii")


def _send_raw(emulator, sock: socket.socket, commands: list[BurstCommand], tally: _ArmTally) -> None:
    from simshear_gym.robots.mg400.protocol import format_command

    for command, target in zip(commands, _targets(np.asarray(emulator.pose), commands)):
        if command.gap_s > 0.0:
            time.sleep(command.gap_s)
        tally.attempted += 1
        text = (format_command("ServoP", *target, t=command.t_s) if command.kind == "ServoP"
                else format_command("MovL", *target))
        reply = _raw_request(sock, text)
        if reply.startswith("0,"):
            tally.sent += 1
        else:
            tally.robot_errors += 1


# ----------------------------------------------------------------------------------------------------------------
# The run and the audit


def _settle(emulator, timeout_s: float) -> None:
    """Wait until the arm is at rest (no motion running), as an operator's script would before the next burst."""
    from simshear_gym.robots.mg400.protocol import RobotMode

    deadline_s = time.monotonic() + timeout_s
    while time.monotonic() < deadline_s and emulator.robot_mode is RobotMode.RUNNING:
        time.sleep(0.005)


def audit_motions(motions, safety_config, tolerance: float = 1e-6) -> dict[str, Any]:
    """Executed motions faster than the limits (speed) and accelerating faster (acceleration), with the peaks."""
    cfg = safety_config
    speed_bad = [m for m in motions if m.peak_speed_mm_s > cfg.max_speed_mm_s * (1 + tolerance) + tolerance
                 or m.peak_rotation_deg_s > cfg.max_speed_deg_s * (1 + tolerance) + tolerance
                 or m.peak_joint_deg_s > cfg.max_speed_deg_s * (1 + tolerance) + tolerance]
    accel_bad = [m for m in motions if m.accel_mm_s2 > cfg.max_accel_mm_s2 * (1 + tolerance) + tolerance
                 or m.accel_deg_s2 > cfg.max_accel_deg_s2 * (1 + tolerance) + tolerance]

    def peak(name: str) -> float:
        return round(max((getattr(m, name) for m in motions), default=0.0), 3)

    return {
        "motions_executed": len(motions),
        "servo_motions": sum(1 for m in motions if m.servo),
        "queued_motions": sum(1 for m in motions if not m.servo),
        "motions_faster_than_the_limit": len(speed_bad),
        "motions_faster_examples": [f"{m.command}: {m.peak_speed_mm_s:.1f} mm/s, R {m.peak_rotation_deg_s:.1f} "
                                    f"deg/s, joint {m.peak_joint_deg_s:.1f} deg/s" for m in speed_bad[:5]],
        "motions_accelerating_faster_than_the_limit": len(accel_bad),
        "motions_accelerating_faster_examples": [
            f"{m.command} at {m.time_s:.3f} s: {m.accel_mm_s2:.0f} mm/s^2, {m.accel_deg_s2:.0f} deg/s^2"
            for m in accel_bad[:5]],
        "peak_speed_mm_s": peak("peak_speed_mm_s"),
        "peak_rotation_deg_s": peak("peak_rotation_deg_s"),
        "peak_joint_deg_s": peak("peak_joint_deg_s"),
        "peak_accel_mm_s2": peak("accel_mm_s2"),
        "peak_accel_deg_s2": peak("accel_deg_s2"),
    }


def run_bursts(config: BurstConfig, guarded: bool = True) -> dict[str, Any]:
    """Send every sequence to every arm at once (through the clients, or raw) and audit the emulators' records."""
    from simshear_gym.real.mg400_client import MG400Client, MG400ClientConfig
    from simshear_gym.real.mg400_emulator import EmulatorConfig, MG400Emulator
    from simshear_gym.real.safety import SafetyConfig, SafetyLayer
    from simshear_gym.robots.mg400.kinematics import inverse

    safety_config = SafetyConfig(servo_over_limit="clamp" if config.clamp else "refuse")
    ready_joints = tuple(float(v) for v in inverse(*READY_POSE_MM_DEG))
    emulators = [MG400Emulator(EmulatorConfig(dashboard_port=0, motion_port=0, feedback_port=0,
                                              initial_joints_deg=ready_joints, **EMULATOR_SPEEDS)).start()
                 for _ in range(config.arms)]
    tallies = [_ArmTally() for _ in emulators]
    clients: list[Any] = []
    sockets: list[socket.socket] = []
    sequences_bad = [0] * config.arms
    started = time.monotonic()
    try:
        for emulator in emulators:
            if guarded:
                client = MG400Client(MG400ClientConfig(
                    host="127.0.0.1", dashboard_port=emulator.dashboard_port, motion_port=emulator.motion_port,
                    feedback_port=emulator.feedback_port, connect_timeout_s=2.0, reply_timeout_s=2.0),
                    SafetyLayer(safety_config)).connect()
                client.enable_robot()
                clients.append(client)
            else:
                with socket.create_connection(("127.0.0.1", emulator.dashboard_port), timeout=2.0) as dashboard:
                    _raw_request(dashboard, "EnableRobot()")
                sock = socket.create_connection(("127.0.0.1", emulator.motion_port), timeout=2.0)
                sockets.append(sock)
        limits = (safety_config.max_step_mm, safety_config.max_speed_mm_s, safety_config.max_step_deg,
                  safety_config.max_speed_deg_s)
        for sequence in range(config.sequences):
            before = [len(emulator.executed_motions()) for emulator in emulators]
            threads = []
            for arm, emulator in enumerate(emulators):
                commands = make_sequence(config, sequence, arm, *limits)
                if guarded:
                    target, args = _send_guarded, (clients[arm], commands, tallies[arm])
                else:
                    target, args = _send_raw, (emulator, sockets[arm], commands, tallies[arm])
                threads.append(threading.Thread(target=target, args=args, name=f"burst-arm-{arm}"))
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            for arm, emulator in enumerate(emulators):
                _settle(emulator, config.settle_timeout_s)
                new = emulator.executed_motions()[before[arm]:]
                if audit_motions(new, safety_config)["motions_faster_than_the_limit"]:
                    sequences_bad[arm] += 1
                if emulator.alarms:  # an overspeed alarm (the raw baseline): clear it, as an operator would
                    tallies[arm].alarms += 1
                    with socket.create_connection(("127.0.0.1", emulator.dashboard_port), timeout=2.0) as dashboard:
                        _raw_request(dashboard, "ClearError()")
                        _raw_request(dashboard, "Continue()")
                    if guarded:
                        clients[arm].reset_reference()
    finally:
        for client in clients:
            client.close()
        for sock in sockets:
            sock.close()
        for emulator in emulators:
            emulator.stop()
    wall_s = time.monotonic() - started
    arms = []
    for arm, (emulator, tally) in enumerate(zip(emulators, tallies)):
        arms.append({"arm": arm, "commands_attempted": tally.attempted, "commands_sent": tally.sent,
                     "refused": dict(sorted(tally.refused.items())),  # type: ignore[union-attr]
                     "answered_with_an_error": tally.robot_errors, "overspeed_alarms": tally.alarms,
                     "unhandled": tally.unhandled, "unhandled_examples": tally.unhandled_examples[:5],
                     "sequences_with_a_motion_faster_than_the_limit": sequences_bad[arm],
                     **audit_motions(emulator.executed_motions(), safety_config)})
    return {
        "mode": ("client, servo targets clamped" if config.clamp else "client") if guarded else "raw (no client)",
        "sequences": config.sequences,
        "arm_sequences": config.sequences * config.arms,
        "arms": arms,
        "arm_sequences_with_a_motion_faster_than_the_limit": int(sum(sequences_bad)),
        "motions_faster_than_the_limit": int(sum(a["motions_faster_than_the_limit"] for a in arms)),
        "motions_accelerating_faster_than_the_limit": int(sum(a["motions_accelerating_faster_than_the_limit"]
                                                              for a in arms)),
        "unhandled": int(sum(a["unhandled"] for a in arms)),
        "wall_s": round(wall_s, 1),
        "_speeds_mm_s": [m.peak_speed_mm_s for e in emulators for m in e.executed_motions()],
    }


def _figure(guarded: dict[str, Any], baseline: dict[str, Any] | None, limit_mm_s: float, path: Path) -> None:
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(7.0, 3.6))
    top = max([limit_mm_s * 1.5] + guarded["_speeds_mm_s"] + (baseline["_speeds_mm_s"] if baseline else []))
    bins = np.linspace(0.0, top, 60)
    if baseline is not None:
        ax.hist(baseline["_speeds_mm_s"], bins=bins, alpha=0.6, color="tab:red",
                label=f"raw commands, no client ({baseline['sequences']} sequences)")
    ax.hist(guarded["_speeds_mm_s"], bins=bins, alpha=0.7, color="tab:blue",
            label=f"through MG400Client ({guarded['sequences']} sequences)")
    ax.axvline(limit_mm_s, color="black", linestyle="--", label=f"max_speed_mm_s = {limit_mm_s:g}")
    ax.set_yscale("log")
    ax.set_xlabel("peak flange speed of each motion the emulated arm executed, mm/s")
    ax.set_ylabel("motions")
    ax.set_title("Bursts of individually valid ServoP / MovL, two arms")
    ax.legend(fontsize=8)
    save_figure(fig, path)


# ----------------------------------------------------------------------------------------------------------------
# Command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``simshear evaluate safety-bursts``."""
    parser.add_argument("--sequences", type=int, default=1000, help="sequences, each sent to every arm (default 1000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every command, gap and t (default 0)")
    parser.add_argument("--arms", type=int, default=2, help="arms, each an emulator with its own client (default 2)")
    parser.add_argument("--baseline-sequences", type=int, default=200,
                        help="the first N sequences also sent raw, without the client (default 200; 0: none)")
    parser.add_argument("--clamp", action="store_true",
                        help="the clients clamp servo targets to the limits instead of refusing them")
    parser.add_argument("--out", type=Path, default=Path("results"),
                        help="results directory for safety_bursts.json and .png (default results)")


def run(args: argparse.Namespace) -> int:
    """Run the benchmark, write the JSON and the figure; 0 when no arm moved faster than the limit."""
    import logging

    from simshear_gym.real.safety import SafetyConfig

    logging.getLogger("simshear_gym.real").setLevel(logging.CRITICAL)  # refusals are counted instead
    if args.baseline_sequences < 0:
        raise ValueError(f"--baseline-sequences must be >= 0, got {args.baseline_sequences}")
    config = BurstConfig(sequences=args.sequences, seed=args.seed, arms=args.arms, clamp=args.clamp)
    guarded = run_bursts(config)
    baseline = None
    if args.baseline_sequences:
        baseline = run_bursts(BurstConfig(sequences=args.baseline_sequences, seed=args.seed, arms=args.arms),
                              guarded=False)
    limits = SafetyConfig()
    figure = args.out / "safety_bursts.png"
    _figure(guarded, baseline, limits.max_speed_mm_s, figure)
    strip = {"_speeds_mm_s"}
    payload = {
        "config": asdict(config),
        "limits": {"max_speed_mm_s": limits.max_speed_mm_s, "max_speed_deg_s": limits.max_speed_deg_s,
                   "max_accel_mm_s2": limits.max_accel_mm_s2, "max_accel_deg_s2": limits.max_accel_deg_s2,
                   "max_step_mm": limits.max_step_mm, "stream_latency_s": limits.stream_latency_s},
        "emulator_speeds_at_100_percent": EMULATOR_SPEEDS,
        "guarded": {k: v for k, v in guarded.items() if k not in strip},
        "baseline_raw": None if baseline is None else {k: v for k, v in baseline.items() if k not in strip},
        "figure": str(figure),
    }
    path = write_record("simshear evaluate safety-bursts", add_arguments, args, args.out / "safety_bursts.json",
                        payload)
    print(f"{guarded['sequences']} sequences x {config.arms} arms through the client: "
          f"{guarded['motions_faster_than_the_limit']} motions faster than the limit in "
          f"{guarded['arm_sequences_with_a_motion_faster_than_the_limit']} of {guarded['arm_sequences']} "
          f"arm-sequences, "
          f"{guarded['motions_accelerating_faster_than_the_limit']} accelerating faster, "
          f"{guarded['unhandled']} unhandled")
    if baseline is not None:
        print(f"raw baseline ({baseline['sequences']} sequences): {baseline['motions_faster_than_the_limit']} motions "
              f"faster than the limit in {baseline['arm_sequences_with_a_motion_faster_than_the_limit']} of "
              f"{baseline['arm_sequences']} arm-sequences")
    print(f"wrote {path} and {figure}")
    return 0 if guarded["motions_faster_than_the_limit"] == 0 and guarded["unhandled"] == 0 else 1
