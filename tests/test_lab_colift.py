"""The co-lift experiment on the rehearsal rig: the layout, the leader's plan, the settings, the rig's object, and
(slow) a co-lift rehearsal end to end and a leader alarm mid-carry stopping both arms."""

from __future__ import annotations

import json
import time
from dataclasses import replace

import numpy as np
import pytest

from simshear_gym.envs.trajectories import Trajectory
from simshear_gym.lab.colift import CoLiftConfig, CoLiftPlan, CoLiftRun
from simshear_gym.lab.colift_layout import (
    COLIFT_LEADER_IN_FOLLOWER_MM_DEG,
    COLIFT_LEADER_START_POSE_MM_DEG,
    OBJECT_FACE_MM,
    ObjectFace,
)
from simshear_gym.lab.endpoints import ArmEndpoint
from simshear_gym.lab.experiment import rehearsal_safety
from simshear_gym.lab.frames import ArmsCalibration, BaseToBase
from simshear_gym.robots.mg400.frames import pose_to_T_base_flange
from tests.test_lab import torch_one_thread  # noqa: F401 - the fixture

# -- fast: layout, plan, settings ---------------------------------------------------------------------------------


def test_the_lab_layout_is_the_colift_scenes():
    from simshear_gym.envs.colift import (
        FOLLOWER_T_WORLD_BASE,
        LEADER_START_POSE_MM_DEG,
        SQUEEZE_MM,
        T_FLANGE_PLATE,
        SimShearCoLiftEnv,
    )
    from simshear_gym.sim.replay import SURFACE_DEPTH_MM
    from simshear_gym.transforms import invert

    assert np.allclose(ObjectFace().T_flange_plate(), T_FLANGE_PLATE)
    assert COLIFT_LEADER_START_POSE_MM_DEG == pytest.approx(LEADER_START_POSE_MM_DEG)
    assert np.allclose(BaseToBase(*COLIFT_LEADER_IN_FOLLOWER_MM_DEG).T_follower_leader(),
                       invert(FOLLOWER_T_WORLD_BASE))
    config = CoLiftConfig()
    assert config.real_env.reference_depth_mm == pytest.approx(SURFACE_DEPTH_MM + SQUEEZE_MM["light"])
    assert config.real_env.estimator_process_std_mm == SimShearCoLiftEnv.servo_hints.process_std_mm


@pytest.mark.parametrize("name", sorted(OBJECT_FACE_MM))
def test_object_faces_are_where_the_scene_places_them(name):
    """The thickness on the grip axis (the face the follower approaches) is where the co-lift scene's reset puts
    the object's face against the plate; the extents are the object's."""
    from dataclasses import replace

    from simshear_gym.envs.colift import LEADER_START_POSE_MM_DEG, T_FLANGE_PLATE
    from simshear_gym.sim.colift_scene import CoLiftScene, CoLiftSceneConfig
    from simshear_gym.sim.objects import OBJECTS
    from simshear_gym.transforms import invert

    T_plate = pose_to_T_base_flange(LEADER_START_POSE_MM_DEG) @ T_FLANGE_PLATE
    with CoLiftScene(replace(CoLiftSceneConfig(object_name=name), settle_s=0.0)) as scene:
        apex = invert(T_plate) @ scene.reset(T_plate, 0.0)
    assert apex[:3, 3] == pytest.approx((0.0, 0.0, ObjectFace(name).thickness_mm), abs=0.01)
    assert OBJECT_FACE_MM[name][:2] == OBJECTS[name].size_mm[:2]


def test_plan_lifts_carries_along_the_env_path_and_sets_down():
    config = CoLiftConfig(trajectory="star", lift_mm=10.0)
    plan = CoLiftPlan(config)
    start = np.array(COLIFT_LEADER_START_POSE_MM_DEG)
    trajectory = Trajectory(config.trajectory_config())
    assert plan.flange_target(0.0) == pytest.approx(start)
    assert plan.flange_target(plan.lift_s) == pytest.approx(start + (0.0, 0.0, 10.0, 0.0))
    for time_s in (0.0, 5.0, 17.3, trajectory.duration_s):  # the co-lift env's offsets, 10 mm up
        offset = trajectory.offset_at(time_s)
        assert plan.flange_target(plan.lift_s + time_s) == pytest.approx(start + (*offset[:3], 0.0) + (0, 0, 10, 0))
    assert plan.flange_target(plan.duration_s) == pytest.approx(plan.flange_target(plan.duration_s + 5.0))
    assert plan.flange_target(plan.duration_s)[2] == pytest.approx(start[2] + trajectory.offset_at(1e9)[2])
    # from rest to rest, never faster than the path's speed (servo commands' t apart)
    times = np.arange(0.0, plan.duration_s + 1.0, config.real_env.servo_time_s)
    targets = np.array([plan.flange_target(t) for t in times])
    speeds = np.linalg.norm(np.diff(targets[:, :3], axis=0), axis=1) / config.real_env.servo_time_s
    assert speeds.max() <= config.speed_mm_s * 1.001 and speeds[0] < 0.5
    assert [plan.phase(t) for t in (0.1, plan.lift_s + 1.0, plan.duration_s - 0.1, plan.duration_s + 1.0)] == [
        "lift", "carry", "lower", "hold"]


def test_config_refuses_bad_values_naming_the_field():
    with pytest.raises(ValueError, match=r"CoLiftConfig.trajectory must be one of \('circular_wave', 'star'\)"):
        CoLiftConfig(trajectory="circle")
    with pytest.raises(ValueError, match="CoLiftConfig.object_name must be one of"):
        CoLiftConfig(object_name="cube")
    with pytest.raises(ValueError, match="CoLiftConfig.rotation_deg must be 0"):
        CoLiftConfig(rotation_deg=5.0)
    with pytest.raises(ValueError, match="CoLiftConfig.lift_mm"):
        CoLiftConfig(lift_mm=-1.0)
    with pytest.raises(ValueError, match="CoLiftConfig.real_env.mount must be a HorizontalTacTipMount"):
        from simshear_gym.contract import TacTipMount

        CoLiftConfig().with_env(mount=TacTipMount())
    with pytest.raises(ValueError, match="CoLiftConfig.start_offset_mm"):
        CoLiftConfig(start_offset_mm=(10.0, 0.0))  # the prism is 30 mm across
    with pytest.raises(ValueError, match="CoLiftConfig.plate must be the ObjectFace of 'egg'"):
        CoLiftConfig(object_name="egg", plate=ObjectFace("prism"))
    assert json.dumps(CoLiftConfig(object_name="ducky").to_dict())  # the record's settings


def test_follower_starts_on_the_grip_axis_before_the_face():
    from simshear_gym.lab.colift_rig import CoLiftRigConfig

    config = CoLiftRigConfig(object_name="egg", hover_mm=5.0)
    T_face = config.face.T_follower_face(config.leader_start_pose_mm_deg,
                                         config.leader_in_follower.T_follower_leader())
    T_sensor = pose_to_T_base_flange(config.follower_start_pose()) @ config.mount.T_flange_sensor()
    assert T_sensor[:3, 3] == pytest.approx(T_face[:3, 3] + 5.0 * T_face[:3, 2])  # 5 mm out of the face
    assert T_sensor[:3, 2] == pytest.approx(-T_face[:3, 2])  # looking into it, horizontally
    assert abs(T_sensor[2, 2]) < 1e-9


def _run(config: CoLiftConfig, truth=None) -> CoLiftRun:
    endpoint = ArmEndpoint("127.0.0.1", 1, 2, 3)
    return CoLiftRun(endpoint, endpoint, None, ArmsCalibration(BaseToBase(*COLIFT_LEADER_IN_FOLLOWER_MM_DEG)),
                     config=config, truth=truth)


def test_the_turn_is_not_sent_and_a_drop_stops():
    run = _run(CoLiftConfig())
    assert isinstance(run.plan, CoLiftPlan)
    assert run._adapt_action(np.array([0.5, -0.5, 0.2, 0.9])) == pytest.approx([0.5, -0.5, 0.2, 0.0])
    row = {"leader_lag_mm": 0.1, "sensor_above_face_mm": -3.0, "on_face": True, "contact_error_mm": 0.3,
           "truth_dropped": True, "truth_object_slip_mm": 21.0}
    stop, why = run._kinematic_stop(row, np.zeros(4))
    assert stop == "dropped" and "fell" in why
    row["truth_dropped"] = False
    assert run._kinematic_stop(row, np.zeros(4)) is None


def test_cli_bad_flags(capsys):
    from simshear_gym.cli import main

    assert main(["experiment", "colift", "--rehearsal", "--leader", "127.0.0.1"]) == 2
    assert "--rehearsal starts its own arms" in capsys.readouterr().err
    assert main(["experiment", "colift", "--leader", "127.0.0.1", "--follower", "127.0.0.2"]) == 2
    assert "give --leader, --follower, --camera and --calibration" in capsys.readouterr().err


# -- slow: on the co-lift rig ---------------------------------------------------------------------------------------

SHORT = dict(scale=0.25, settle_s=2.0, hold_s=0.5, lift_mm=5.0,
             real_env=replace(CoLiftConfig.real_env, safety=rehearsal_safety()))


@pytest.mark.slow
@pytest.mark.usefixtures("torch_one_thread")
def test_colift_rehearsal_end_to_end(tmp_path):
    """Grasp, lift, carry along the path, set down, release: no drop, the calibrated contact error is the rig's true
    one, no command outside the limits in either emulator's record, the follower backed off along the grip axis."""
    from simshear_gym.lab.colift import run_colift_rehearsal

    config = CoLiftConfig(trajectory="circular_wave", object_name="prism", **SHORT)
    summary = run_colift_rehearsal(config, tmp_path, command="test")
    rows = summary.pop("rows")
    assert summary["completed"], summary["stop_reason"]
    assert summary["commands_outside_limits"] == 0, summary["audit"]
    assert not summary["dropped"] and not summary["truth_dropped"]
    assert summary["truth_object_slip_max_mm"] < 5.0
    cycle_s = config.real_env.servo_time_s
    assert summary["tracking_cycles"] >= (summary["trajectory_duration_s"] + config.hold_s) / cycle_s
    assert summary["contact_error_mean_mm"] < 2.0
    assert summary["contact_error_mean_mm"] == pytest.approx(summary["truth_contact_error_mean_mm"], abs=0.1)
    phases = [row["phase"] for row in rows]
    assert phases[0] == "approach" and "settle" in phases and phases[-1] == "track"
    carried = [row for row in rows if row["truth_carried"]]
    assert carried and all(row["truth_in_contact"] for row in carried)
    follower_z = np.array([row["follower_z_mm"] for row in carried])
    assert np.ptp(follower_z) > config.lift_mm  # the follower went up with the object
    for name in ("log.csv", "experiment.json", "experiment.png"):
        assert (tmp_path / name).is_file()
    written = json.loads((tmp_path / "experiment.json").read_text())
    assert written["command"] == "test" and written["object"] == "prism"
    assert written["audit"] == {"leader": [], "follower": []}


@pytest.mark.slow
@pytest.mark.usefixtures("torch_one_thread")
def test_leader_alarm_mid_carry_stops_both_arms_and_a_rerun_works(tmp_path):
    from simshear_gym.lab.colift import run_colift_rehearsal
    from simshear_gym.lab.colift_rig import CoLiftRig, CoLiftRigConfig

    config = CoLiftConfig(trajectory="star", object_name="egg", **SHORT)
    injected: dict[str, int] = {}

    def on_cycle(row) -> None:
        if row["colift_phase"] == "carry" and "cycle" not in injected:
            injected["cycle"] = row["cycle"]
            rig.leader.inject_alarm(22)

    with CoLiftRig(CoLiftRigConfig(object_name="egg")) as rig:
        summary = run_colift_rehearsal(config, tmp_path / "fault", on_cycle=on_cycle, rig=rig)
        assert summary["stop"] == "leader_robot_error", summary["stop_reason"]
        rows = summary["rows"]
        assert [row["cycle"] for row in rows] == list(range(len(rows)))  # complete, one row per cycle
        assert rows[-1]["stop"] == "leader_robot_error" and all(row["stop"] == "" for row in rows[:-1])
        assert rows[-1]["cycle"] - injected["cycle"] <= 2
        sent = len(rig.leader.motion_records()), len(rig.follower.motion_records())
        still = rig.leader.pose, rig.follower.pose
        time.sleep(0.3)  # longer than a servo command's t: both arms reached their last target and stay
        assert np.allclose(rig.leader.pose, still[0], atol=1e-6) and np.allclose(rig.follower.pose, still[1],
                                                                                atol=1e-6)
        assert (len(rig.leader.motion_records()), len(rig.follower.motion_records())) == sent
        assert summary["commands_outside_limits"] == 0, summary["audit"]

        rig.clear_alarms()  # the operator's recovery; the object goes back on its support (a fresh camera)
        again = run_colift_rehearsal(config, tmp_path / "rerun", rig=rig)
        assert again["completed"], again["stop_reason"]
        assert again["commands_outside_limits"] == 0, again["audit"]
        assert not again["dropped"]


@pytest.mark.slow
@pytest.mark.usefixtures("torch_one_thread")
def test_a_drop_mid_carry_stops_both_arms(tmp_path):
    """The object knocked out of the grip while carried: the run stops (the GDNN's grip lost or the rig's drop),
    reports the drop, both arms stay where they were, nothing outside the limits."""
    from simshear_gym.lab.colift import run_colift_rehearsal
    from simshear_gym.lab.colift_rig import CoLiftRig, CoLiftRigConfig

    config = CoLiftConfig(trajectory="circular_wave", object_name="prism", **SHORT)
    injected: dict[str, int] = {}

    def on_cycle(row) -> None:
        if row["colift_phase"] == "carry" and "cycle" not in injected:
            injected["cycle"] = row["cycle"]
            rig.camera.knock((0.0, 0.0, -5000.0))

    with CoLiftRig(CoLiftRigConfig(object_name="prism")) as rig:
        summary = run_colift_rehearsal(config, tmp_path, on_cycle=on_cycle, rig=rig)
        assert summary["stop"] in ("dropped", "follower_lost_contact", "lost_contact"), summary["stop_reason"]
        assert summary["dropped"] and summary["truth_dropped"]
        assert summary["rows"][-1]["cycle"] - injected["cycle"] <= 5
        sent = len(rig.leader.motion_records()), len(rig.follower.motion_records())
        time.sleep(0.3)
        assert (len(rig.leader.motion_records()), len(rig.follower.motion_records())) == sent
        assert summary["commands_outside_limits"] == 0, summary["audit"]
