"""``simshear collect-real`` on the rehearsal (an emulated MG400 and a camera rendering the configured face): the
touch-off finds the face, every row's image and label land whole, a stopped run continues at the next row, no
command the emulator received breaks the safety limits, and the set's config stub passes ``pipeline check``."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from simshear_gym.cli import main
from simshear_gym.lab.collect_protocol import CollectProtocol
from simshear_gym.lab.collect_real import Rehearsal, collect, connect
from simshear_gym.lab.experiment import rehearsal_safety
from simshear_gym.lab.rig import audit_motion_records
from simshear_gym.real.camera import default_config, preprocess
from tests.test_collect_protocol import TOML

PROTOCOL = CollectProtocol(stimulus="surface", work_origin_base_mm=(300.0, 0.0, -110.0), rows=6, seed=2,
                           ranges={"pose_z": (3.0, 5.0), "move_x": (-2.0, 2.0), "move_y": (-2.0, 2.0)})


def frames_to_image(frame):
    return preprocess(frame, default_config())


@pytest.mark.slow
def test_rehearsed_collection_touches_off_records_whole_rows_and_resumes(tmp_path):
    safety = rehearsal_safety()
    with Rehearsal(PROTOCOL) as rig:
        with connect(rig.endpoint, safety) as client:
            first = collect(PROTOCOL, client, rig.camera, tmp_path / "set", frames_to_image, stop_after_rows=2)
        assert first["rows"] == 2 and not first["complete"]
        assert abs(first["touch_off"]["face_z_base_mm"] - (-110.0)) <= 0.1  # the onset, from the change-depth line
        with connect(rig.endpoint, safety) as client:
            second = collect(PROTOCOL, client, rig.camera, tmp_path / "set", frames_to_image)
        assert second["resumed_at"] == 2 and second["rows"] == 6 and second["complete"]
        records = rig.emulator.motion_records()
        assert records and audit_motion_records(records, safety) == []
        final_z = rig.emulator.pose[2]
    table = pd.read_csv(tmp_path / "set" / "targets.csv")
    rows = PROTOCOL.draw_rows()
    columns = [f"pose_{i}" for i in range(1, 7)] + [f"move_{i}" for i in range(1, 7)]
    np.testing.assert_allclose(table[columns].to_numpy(), rows[columns].to_numpy())
    assert list(table["sensor_image"]) == [f"image_{i}.png" for i in range(1, 7)]
    images = sorted((tmp_path / "set" / "images").iterdir())
    assert [p.name for p in images] == sorted(table["sensor_image"]) and all(p.stat().st_size > 0 for p in images)
    face_apex_clear = final_z - 95.0 - (-110.0)
    assert face_apex_clear >= PROTOCOL.hover_mm - 0.1  # lifted clear at the end


def test_another_protocols_folder_is_refused(tmp_path):
    from simshear_gym.lab.collect_real import CollectError, _done_rows

    (tmp_path / "targets.csv").write_text("sensor_image\n")
    (tmp_path / "meta.json").write_text('{"protocol": {"rows": 1}}')
    with pytest.raises(CollectError, match="holds rows of another \\[collect\\] protocol"):
        _done_rows(tmp_path, replace(PROTOCOL, rows=7))


CONFIG = TOML.replace("rows = 6", "rows = 500").replace("-100.0]", "-110.0]")  # a [collect] protocol


def test_dry_run_prints_the_plan_and_moves_nothing(tmp_path, capsys):
    config = tmp_path / "lab.toml"
    config.write_text(CONFIG)
    assert main(["collect-real", str(config), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "500 surface rows" in out and "robot time per row" in out
    mean_s = float(out.split("robot time per row ")[1].split(" s mean")[0])
    assert 0.3 < mean_s < 1.0


@pytest.mark.slow
def test_the_command_rehearses_and_its_config_stub_passes_pipeline_check(tmp_path, capsys):
    from simshear_gym.pipelines.check import check
    from simshear_gym.pipelines.config import load_config

    config = tmp_path / "lab.toml"
    config.write_text(CONFIG)
    out = tmp_path / "set"
    assert main(["collect-real", str(config), "--rehearsal", "--rows", "12", "--out", str(out)]) == 0
    assert "12/12 rows" in capsys.readouterr().out
    (report,) = check(load_config(out / "config_stub.toml"), tmp_path)
    assert report.rows["train"] + report.rows["val"] == 12 and report.contact_share == 1.0
    assert {v["name"] for v in report.variables if v["varies"]} == {"pose_z", "move_x", "move_y"}


@pytest.mark.slow
def test_the_benchmark_kills_and_resumes_on_both_stimuli(tmp_path):
    """``simshear evaluate collect-real`` at a few rows: the collector killed with SIGKILL mid-run and rerun."""
    import json

    assert main(["evaluate", "collect-real", "--rows", "8", "--out", str(tmp_path)]) == 0
    record = json.loads((tmp_path / "collect_real.json").read_text())
    assert record["command"].startswith("simshear evaluate collect-real") and (tmp_path / "collect_real.png").is_file()
    for result in record["results"]:
        assert result["rows"] == 8 and 1 <= result["killed_at_row"] < 8
        assert (result["duplicate_images"], result["missing_images"], result["undecodable_images"],
                result["labels_outside_ranges"], result["emulator_commands_outside_limits"]) == (0, 0, 0, 0, 0)
        assert result["stray_files"] == [] and result["emulator_commands"] > 8 * 3
        assert result["labels_match_protocol_rows"]
