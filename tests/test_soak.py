"""The fault soak (issue 24, bullet 3): the servo controller drives RealTactileEnv against the MG400 emulator and a
replayed camera while faults are injected at random; nothing goes outside the limits, nothing is unhandled, and
every fault ends as a safe stop or a recovery. The record run is ``simshear evaluate soak`` (results/soak.json)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from simshear_gym.contract import ActionScale, TacTipMount
from simshear_gym.evaluate.soak import (
    FAULT_KINDS,
    SoakConfig,
    audit,
    braking_margin_mm,
    fault_schedule,
    keep_in_box,
    run_soak,
    safety_config,
    soak_env,
    synthetic_frames,
)
from simshear_gym.real.env import move_to_flange_target
from simshear_gym.real.mg400_emulator import READY_JOINTS_DEG, READY_POSE_MM_DEG, MotionRecord
from simshear_gym.real.safety import SafetyLayer
from simshear_gym.robots.mg400.kinematics import inverse


def posenet_path() -> str:
    from simshear_gym.models.zoo import posenet_weights

    return str(posenet_weights("surface"))


def check(result: dict, cycles: int) -> None:
    assert result["cycles"] == cycles
    assert result["commands_outside_limits"] == 0, result["commands_outside_limits_examples"]
    assert result["unhandled_exceptions"] == 0, result["unhandled_examples"]
    assert result["faults_unaccounted"] == 0
    for kind in FAULT_KINDS:
        injected = result["faults_injected"][kind]
        assert injected >= 1, f"{kind} was never injected"
        outcomes = result["fault_outcomes"][kind]
        assert set(outcomes) <= {"safe_stop", "recovered"} and sum(outcomes.values()) == injected, (kind, outcomes)
    fault_stops = sum(outcomes.get("safe_stop", 0) for outcomes in result["fault_outcomes"].values())
    assert fault_stops + sum(result["stops_without_a_fault"].values()) == result["safe_stops_total"]
    assert "unhandled" not in result["safe_stops"]
    # every stop was followed by a reset that started a new episode (the last one may have ended the run)
    assert result["safe_stops_total"] - 1 <= result["recoveries"] <= result["safe_stops_total"]
    assert result["servo_commands_sent"] > cycles // 2
    assert result["motions_faster_than_the_limit"] == 0, result["motions_faster_examples"]
    # the faults injected are the schedule's, decided before the run from the seed
    scheduled = [kind for kind, start, _, _ in result["fault_schedule"] if start < cycles]
    assert result["faults_total"] == len(scheduled)
    assert all(result["faults_injected"][kind] == scheduled.count(kind) for kind in FAULT_KINDS)


def test_a_seeded_soak_stays_within_the_limits_and_handles_every_fault():
    cycles = 420
    result = run_soak(SoakConfig(cycles=cycles, seed=3, mean_gap_cycles=8.0,
                                 real_env=replace(soak_env(), posenet=posenet_path())),
                      synthetic_frames(seed=3))
    check(result, cycles)
    # the faults that must stop an episode did
    for kind in ("dropped_connection", "inconsistent_feedback", "alarm_mid_motion", "camera_stall", "nan_estimate"):
        assert result["fault_outcomes"][kind].get("safe_stop", 0) >= 1, (kind, result["fault_outcomes"][kind])
    # the ones a healthy client rides through did not stop it
    for kind in ("split_replies", "partial_feedback", "corrupt_feedback"):
        assert result["fault_outcomes"][kind].get("recovered", 0) >= 1, (kind, result["fault_outcomes"][kind])


def _record(command: str, target, in_force=READY_POSE_MM_DEG, servo: bool = True, t_s: float = 0.04,
            error_id: int = 0) -> MotionRecord:
    in_force_joints = tuple(inverse(*in_force))
    return MotionRecord(0.0, command, servo, tuple(target), tuple(inverse(*target)), t_s if servo else None,
                        tuple(in_force), in_force_joints, tuple(in_force), error_id)


def test_the_audit_counts_commands_outside_the_limits():
    safety = SafetyLayer(safety_config())
    x, y, z, r = READY_POSE_MM_DEG
    assert READY_JOINTS_DEG == pytest.approx(inverse(*READY_POSE_MM_DEG))
    fine = [_record("ServoP(a)", (x + 1.0, y, z, r)),
            _record("ServoP(b)", (x + 2.0, y, z, r), in_force=(x + 1.0, y, z, r))]
    assert audit(fine, safety) == (0, [])
    too_far = _record("ServoP(c)", (x + 6.0, y, z, r))  # 6 mm > max_step_mm
    too_fast = _record("ServoP(d)", (x + 4.0, y, z, r), t_s=0.04)  # 100 mm/s > 50 mm/s
    outside = _record("ServoP(e)", (x, y, z + 26.0, r), in_force=(x, y, z + 25.0, r))  # z beyond the soak's box
    jump = _record("MovJ(f)", (x, y + 20.0, z - 20.0, r), servo=False)  # 28 mm: within the 50 mm jump
    for bad, reason in ((too_far, "step 6.000 mm"), (too_fast, "speed 100.0 mm/s"), (outside, "z = 26.000 outside")):
        count, examples = audit([bad], safety)
        assert count == 1 and reason in examples[0], examples
    assert audit([jump], safety) == (0, [])
    # a command the robot refused (in error mode) is measured from the last target it accepted, not from where
    # an alarm stopped the arm
    halted = _record("ServoP(g)", (x + 2.0, y, z, r), in_force=(x + 0.5, y, z, r), error_id=-1)
    assert audit([fine[0], halted], safety)[0] == 0
    executed = _record("ServoP(h)", (x + 2.0, y, z, r), in_force=(x - 0.5, y, z, r), t_s=0.04)  # 62.5 mm/s
    assert audit([fine[0], executed], safety)[0] == 1


def test_the_fault_schedule_is_decided_up_front_from_the_seed():
    config = SoakConfig(cycles=2000, seed=5)
    schedule = fault_schedule(config)
    assert schedule == fault_schedule(SoakConfig(cycles=2000, seed=5))
    assert schedule != fault_schedule(SoakConfig(cycles=2000, seed=6))
    assert {fault.kind for fault in schedule[:len(FAULT_KINDS)]} == set(FAULT_KINDS)  # each kind once a round
    for before, after in zip(schedule, schedule[1:]):  # windows never overlap
        assert after.start_cycle > before.start_cycle + before.cycles
    assert all(fault.start_cycle < config.cycles for fault in schedule)


def test_the_controller_keeps_its_targets_inside_the_soak_box():
    safety = SafetyLayer(safety_config())
    margin_mm = braking_margin_mm(safety, 0.1)
    assert margin_mm == pytest.approx(50.0 * 0.1 + 50.0 ** 2 / (2 * 2000.0) + 1.0)
    scale, mount = ActionScale(), TacTipMount()
    low_z = safety.config.z_range_mm[0] + margin_mm
    commanded = np.array([300.0, 0.0, low_z + 0.3, 0.0])
    down = np.array([0.5, 0.0, 1.0, 0.0])  # +z of the sensor: the flange goes down, 1 mm a step
    kept = keep_in_box(down, commanded, safety, scale, mount, margin_mm)
    target = move_to_flange_target(commanded, kept * scale.as_array(), mount)
    assert target[2] == pytest.approx(low_z, abs=1e-6) and target[2] >= low_z  # scaled back, direction kept
    assert kept[0] / kept[2] == pytest.approx(0.5) and kept[3] == down[3]
    inside = np.array([0.2, -0.3, -0.5, 0.4])
    assert keep_in_box(inside, commanded, safety, scale, mount, margin_mm) is not None
    assert np.array_equal(keep_in_box(inside, commanded, safety, scale, mount, margin_mm), inside)
