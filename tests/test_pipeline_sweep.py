"""``simshear pipeline sweep``: the chain and a GDNN on the first N real rows per budget, beside the reference on all
rows, on the same complete validation rows; one record and figure per contact type; every step cached."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from simshear_gym.cli import main
from simshear_gym.pipelines.sweep import (
    ROBOT_S_PER_ROW,
    Budget,
    check_budgets,
    epoch_scale,
    parse_budgets,
    scaled,
    subset_rows,
)

ROOT = Path(__file__).resolve().parents[1]


def test_budgets_are_sorted_with_all_last():
    assert parse_budgets(["all", "1000", "250"]) == (Budget(250), Budget(1000), Budget(None))
    assert [b.label for b in parse_budgets(["ALL", "2"])] == ["2", "all"]


@pytest.mark.parametrize(("values", "named"), [(["250", "lots"], "'lots'"), (["0"], "'0'"), (["-5"], "'-5'"),
                                               (["2.5"], "'2.5'"), (["250", "250"], "'250'"), ([], "no budget")])
def test_a_bad_budget_is_named(values, named):
    with pytest.raises(ValueError, match="--real-rows") as error:
        parse_budgets(values)
    assert named in str(error.value)


def test_a_budget_must_leave_rows_out_of_every_dataset():
    check_budgets((Budget(10), Budget(None)), {"tap": 48, "shear": 30})
    with pytest.raises(ValueError, match=r"--real-rows: 30 is not below the 30 training rows of dataset 'shear'"):
        check_budgets((Budget(30),), {"tap": 48, "shear": 30})


def test_epochs_scale_by_all_over_n_up_to_the_cap_only_when_asked():
    assert epoch_scale(Budget(250), 250, 5000, None) == 1.0
    assert epoch_scale(Budget(250), 250, 5000, 4.0) == 4.0
    assert epoch_scale(Budget(2500), 2500, 5000, 4.0) == 2.0
    assert epoch_scale(Budget(None), 5000, 5000, 4.0) == 1.0
    assert scaled(14, 2.0) == 28 and scaled(1, 0.2) == 1
    assert ROBOT_S_PER_ROW == pytest.approx(1.56)


def test_the_command_names_a_bad_budget_in_one_line(capsys):
    code = main(["pipeline", "sweep", str(ROOT / "configs" / "example_lab.toml"), "--real-rows", "250", "many"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "'many'" in err and "'all'" in err


def test_the_command_rejects_a_scale_cap_below_one(tmp_path, capsys):
    code = main(["pipeline", "sweep", str(ROOT / "configs" / "example_lab.toml"), "--real-rows", "8",
                 "--scale-epochs", "0.5", "--data", str(tmp_path), "--out", str(tmp_path / "run")])
    assert code == 2
    assert "--scale-epochs: 0.5" in capsys.readouterr().err


@pytest.mark.slow
def test_example_lab_smoke_sweep_writes_a_record_and_figure_per_contact_and_reruns_from_cache(
        data_root, tmp_path, monkeypatch):
    from simshear_gym.pipelines.example_sensor import make_example

    make_example(data_root, tmp_path / "lab", rows_per_split=48)
    monkeypatch.chdir(tmp_path)
    argv = ["pipeline", "sweep", str(ROOT / "configs" / "example_lab.toml"), "--real-rows", "16", "all",
            "--profile", "smoke", "--data", "lab", "--out", "run", "--record", "records/sweep", "--workers", "1",
            "--scale-epochs", "2"]
    assert main(argv) == 0
    record = json.loads((tmp_path / "records" / "sweep_surface.json").read_text())
    assert (tmp_path / "records" / "sweep_surface.png").stat().st_size > 0
    assert record["command"].startswith("simshear pipeline sweep ") and "--real-rows 16 all" in record["command"]
    assert "--workers 1" in record["command"] and "--scale-epochs 2 " in record["command"]
    assert record["produced_by"] and record["date"] and record["purpose"]  # smoke: a plumbing check, said so
    assert set(record["load_1min"]) == {"start", "end"}
    assert record["run_folder"] == "run" and record["figure"] == "records/sweep_surface.png"
    assert record["train_rows"] == {"surface_tap": 48} and record["val_rows"] == {"surface_tap": 48}
    small, full = record["budgets"]
    assert small["rows_per_dataset"] == {"surface_tap": 16} and full["rows_per_dataset"] == {"surface_tap": 48}
    assert small["robot_minutes"] == pytest.approx(16 * 1.56 / 60, abs=0.01)
    assert small["epochs"]["factor"] == 2.0 and small["epochs"]["translator"] == 2
    assert full["epochs"]["factor"] == 1.0
    for entry in (small, full):
        figures = entry["datasets"]["surface_tap"]
        assert figures["val_rows"] == 24  # the smoke profile's eval rows, the same for every budget
        for source in ("chain", "real_rows", "reference"):
            assert set(figures["mae"][source]) == {"z_mm", "rx_deg", "ry_deg"}
        assert set(figures["mape"]) == {"translator", "retrieval"}
        assert all(isinstance(n, int) and n > 0 for n in entry["optimiser_steps"].values())
        assert set(entry["stage_wall_s"]) == {"translator", "chain", "real_rows", "reference"}
    # the reference is one model; at 'all' the GDNN on N real rows is the reference
    assert small["datasets"]["surface_tap"]["mae"]["reference"] == full["datasets"]["surface_tap"]["mae"]["reference"]
    assert full["datasets"]["surface_tap"]["mae"]["real_rows"] == full["datasets"]["surface_tap"]["mae"]["reference"]
    assert small["optimiser_steps"]["translator"] < full["optimiser_steps"]["translator"] * 2
    text = (tmp_path / "records" / "sweep_surface.json").read_text()
    assert str(tmp_path) not in text  # relative paths only
    subset = next((tmp_path / "run" / "rows" / "surface_tap").glob("*/set/targets.csv"))
    assert sum(1 for _ in subset.open()) == 17  # header + the first 16 rows

    logged = []
    from simshear_gym.pipelines.config import load_config
    from simshear_gym.pipelines.sweep import parse_budgets, run_sweep

    config = load_config(ROOT / "configs" / "example_lab.toml")
    again = run_sweep(config, Path("run"), Path("lab"), "smoke", parse_budgets(["16", "all"]), scale_cap=2.0,
                      workers=1, log=logged.append)
    assert not [line for line in logged if "running" in line], logged  # every step cached
    assert again["stages"]["ran"] == 0 and again["stages"]["cached"] > 0 and record["stages"]["ran"] > 0
    assert again["budgets"]["surface"] == record["budgets"]


def test_a_budget_trains_the_profiles_pool_on_its_rows_read_by_its_own_real_gdnn():
    """A pool generator with the pose-consistency loss is trained on the budget's N pairs and read by the GDNN on
    the same N real images (at 'all': the reference), its epochs scaled as the shPix2pix's; the chain draws it."""
    from dataclasses import replace

    from simshear_gym.pipelines.config import PoolGenerator, load_config
    from simshear_gym.pipelines.sweep import budget_steps, sweep_profile

    config = load_config(ROOT / "configs" / "example_lab.toml")
    profile = sweep_profile(config, "smoke")
    pool = (PoolGenerator("tilt", "surface", draws=2, overrides={"pose_weight": 20.0, "epochs": 3}),
            PoolGenerator("plain", "surface"))
    profile = replace(profile, pool=pool)
    paired = {"surface_tap": {"train": "collect/train", "val": "collect/val"}}
    cases = ((Budget(16), "posenet/surface_real_rows", 6), (Budget(None), "posenet/surface_real", 3))
    for budget, reader, epochs in cases:
        subsets = {"surface_tap": "rows/set" if budget.rows else "collect/train"}
        steps, _ = budget_steps(config, profile, budget, paired, subsets, {}, {"surface": "surface"}, "cpu", 2.0,
                                {"surface_tap": 48})
        by_name = {step.name: step for step in steps}
        tilt, plain = by_name["translator/surface_tilt"], by_name["translator/surface_plain"]
        assert tilt.needs == (reader,) and plain.needs == ()
        assert tilt.action.keywords["reader"] == reader and plain.action.keywords["reader"] is None
        assert tilt.action.args[4] == [subsets["surface_tap"]]  # trained on the budget's pairs
        assert tilt.action.args[5].overrides["epochs"] == epochs  # its own epochs, scaled by all/N (cap 2)
        chain = by_name["posenet/surface_shpix2pix"]
        assert chain.needs == ("translator/surface_shpix2pix", "translator/surface_tilt", "translator/surface_plain")
        assert chain.action.args[6] == (("translator/surface_shpix2pix", 1), ("translator/surface_tilt", 2),
                                        ("translator/surface_plain", 1))


def test_a_budgets_rows_are_a_seeded_random_draw_nested_in_larger_budgets_or_the_first_n():
    """A set sorted by a label (tactip331's edge sets are sorted by the edge angle) must not give a budget only one
    end of that label's range: by default a budget's rows are one fixed permutation's first N, in the set's order."""
    small, large = subset_rows(5000, 250, "random"), subset_rows(5000, 1000, "random")
    assert len(small) == 250 and len(set(small)) == 250 and list(small) == sorted(small)
    assert set(small) <= set(large)  # a smaller budget's rows are among a larger one's
    assert list(subset_rows(5000, 250, "random")) == list(small)  # the same draw every time
    assert small.max() > 4000 and small.min() < 1000  # spread over the whole set, not its start
    assert list(subset_rows(5000, 3, "first")) == [0, 1, 2]
    with pytest.raises(ValueError, match="--rows-from: 'last'"):
        subset_rows(10, 3, "last")
