"""``simshear pipeline run``: stages cached under a content hash (a rerun does nothing), an interrupted stage rerun
in its own folder, new settings in a new folder; a manifest per run."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import gymnasium as gym
import pytest

import simshear_gym.envs  # noqa: F401  (registers the envs)
from simshear_gym.control.pi_law import PIGains
from simshear_gym.control.servo import ServoController
from simshear_gym.data.tactile_set import read_set
from simshear_gym.models.onnx_export import missing_export_packages
from simshear_gym.models.translator_runtime import (
    OnnxTranslator,
    load_translator,
    onnx_path_for,
    runtime_of,
    translator_from,
)
from simshear_gym.pipelines.config import load_config
from simshear_gym.pipelines.example_sensor import make_example
from simshear_gym.pipelines.run import STAGES, contacts_of, only_contacts, run_pipeline
from tests.test_pipeline_check import GOOD, write_lab

ROOT = Path(__file__).resolve().parents[1]


def test_rerun_is_cached_and_an_interrupted_stage_reruns_in_its_folder(tmp_path):
    data = tmp_path / "data"
    config = load_config(write_lab(data))
    out = tmp_path / "run"
    first = run_pipeline(config, out, data, "smoke", ("adapt", "collect"), rows_per_split=None, workers=1)
    assert [r["ran"] for r in first["results"]] == [True, True]
    paired = read_set(out / first["results"][1]["folder"] / "train")
    assert len(paired) == 8 and paired.meta["tactip"]["dome_radius_mm"] == config.sensor.dome_radius_mm
    assert paired.images_dir.is_dir()

    second = run_pipeline(config, out, data, "smoke", ("adapt", "collect"), rows_per_split=None, workers=1)
    assert [r["ran"] for r in second["results"]] == [False, False]
    assert [r["folder"] for r in second["results"]] == [r["folder"] for r in first["results"]]

    collect_folder = out / first["results"][1]["folder"]
    (collect_folder / "stage.json").unlink()  # killed before the record: the stage runs again, same folder
    shutil.rmtree(collect_folder / "val")
    third = run_pipeline(config, out, data, "smoke", ("adapt", "collect"), rows_per_split=None, workers=1)
    assert [r["ran"] for r in third["results"]] == [False, True]
    record = json.loads((collect_folder / "stage.json").read_text())
    assert record["resumed"] and record["metrics"] == {"train": 8, "val": 4}

    fewer = run_pipeline(config, out, data, "smoke", ("adapt",), rows_per_split=3, workers=1)
    assert fewer["results"][0]["ran"] and fewer["results"][0]["folder"] != first["results"][0]["folder"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sensor"] == "lab" and manifest["git_commit"] and manifest["profile"] == "smoke"
    machine = manifest["machine"]  # wall times of two machines can be told apart
    assert machine["cpus"] >= 1 and machine["processor"] and machine["torch_cpu_capability"]


def test_smoke_profile_runs_every_stage_and_reruns_from_cache(tmp_path):
    data = tmp_path / "data"
    config = load_config(write_lab(data, rows=30))
    out = tmp_path / "run"
    stages = ("adapt", "collect", "translator", "posenet", "evaluate")
    manifest = run_pipeline(config, out, data, "smoke", stages, workers=1)
    assert all(result["ran"] for result in manifest["results"])
    evaluation = json.loads((out / manifest["evaluation"]).read_text())
    assert set(evaluation["translation"]["tap"]) == {"rows", "shpix2pix", "pix2pix", "nearest-label retrieval"}
    # the lab's varying variables, in the simulation's frame: depth (lab y) and Rx (lab roll); nothing else
    assert [spec.split(":")[0] for spec in evaluation["variables"]["surface"].split(",")] == ["z_mm", "rx_deg"]
    assert set(evaluation["posenet"]["tap"]["ratio_shpix2pix_to_real"]) == {"z_mm", "rx_deg"}
    for path in (manifest["models"]["translators"]["surface"]["shpix2pix"],
                 manifest["models"]["posenets"]["models"]["surface"]["shpix2pix"]):
        assert (out / path).is_file() and not path.startswith("/")
    again = run_pipeline(config, out, data, "smoke", stages, workers=1)
    assert not any(result["ran"] for result in again["results"])

    # the sensor's translator is exported to ONNX beside its weights, where the envs' "auto" runtime takes it
    weights = out / manifest["models"]["translators"]["surface"]["shpix2pix"]
    exported = not missing_export_packages()
    sensor = json.loads((out / "sensor.json").read_text())
    assert sensor["onnx"] == ({"surface": str(onnx_path_for(weights).relative_to(out))} if exported else {})
    assert [r["stage"] for r in manifest["results"] if r["stage"].startswith("onnx/")] == (
        ["onnx/surface_shpix2pix"] if exported else [])
    if exported:
        check = next(r for r in manifest["results"] if r["stage"] == "onnx/surface_shpix2pix")["metrics"]
        assert check["sets"]["tap_val"]["max_abs_difference_grey"] <= 2
        assert isinstance(load_translator(weights, "auto"), OnnxTranslator)

    # the envs and the servo controller take the sensor's own models from the run folder
    env = gym.make("SimShearTracking-v0", sensor=str(out), obs_mode="real")
    base = env.unwrapped
    assert base.tactip.config.dome_radius_mm == config.sensor.dome_radius_mm
    assert base.translator_weights == str(weights)
    if exported:  # the env runs it on ONNX Runtime, as it does the shipped translators
        assert runtime_of(translator_from(base.translator_weights)) == "onnx"
    with pytest.raises(ValueError, match=r"does not read \['shear_x_mm', 'shear_y_mm'\], which the servo law "
                                         r"steers on"):
        ServoController.for_env(env)  # a tap-only sensor: no shear to servo on
    controller = ServoController.for_env(env, gains=PIGains(kp=(0.0, 0.0, 0.5, 0.0), ki=(0.0, 0.0, 0.1, 0.0)))
    assert controller.estimator.unread == ("shear_x_mm", "shear_y_mm", "shear_rz_deg")
    observation, _ = env.reset(seed=0)
    controller.reset()
    for _ in range(5):
        action = controller(observation)
        assert env.action_space.contains(action)
        observation, _, terminated, truncated, _ = env.step(action)
        assert observation["tactile"].shape == (1, 128, 128)
        if terminated or truncated:
            break
    env.close()


def test_without_the_export_extra_the_run_says_so_and_keeps_the_torch_translators(tmp_path, monkeypatch):
    from simshear_gym.models import onnx_export
    from simshear_gym.pipelines.run import stage_onnx
    from simshear_gym.pipelines.stages import StageRunner

    monkeypatch.setattr(onnx_export, "missing_export_packages", lambda: ["onnxscript"])
    lines = []
    runner = StageRunner(tmp_path, log=lines.append)
    assert stage_onnx(runner, {"surface": "translator/x/shpix2pix_surface.pt"}, {"tap": {"val": "v"}},
                      {"surface": ["tap"]}) == {}
    assert len(lines) == 1 and "onnxscript" in lines[0] and "torch" in lines[0] and not runner.results


def test_a_stage_stopped_by_its_cap_stops_the_run_and_the_reruns_train_the_recipes_model(tmp_path, monkeypatch):
    """A machine too slow for a translator's cap: each run stops there without a record; the reruns finish the
    stage in its folder with the weights an uncapped run gives (so a recipe rebuilds on any machine)."""
    import torch

    from simshear_gym.models.translator import load_generator
    from simshear_gym.pipelines.stages import StageStopped
    from simshear_gym.train.loop import EpochTrainer
    from simshear_gym.train.translator_trainer import TranslatorTrainer
    from tests.clocks import StepClock

    profile = '\n[profiles.smoke.translator]\narchs = ["shpix2pix"]\nepochs = 6\n'
    data = tmp_path / "data"
    straight = run_pipeline(load_config(write_lab(data, rows=30, config=GOOD + profile)), tmp_path / "straight",
                            data, "smoke", ("adapt", "collect", "translator"), workers=1)
    clock = StepClock()  # a slower machine: 1/16 s a step on the trainers' clock
    step = TranslatorTrainer.train_batch
    monkeypatch.setattr(EpochTrainer, "clock", clock)
    monkeypatch.setattr(TranslatorTrainer, "train_batch",
                        lambda self, index: (clock.advance(1 / 16), step(self, index))[1])
    capped = load_config(write_lab(data, rows=30, config=GOOD + profile + "cap_minutes = 0.01\n"))
    stops = 0
    for _ in range(12):
        try:
            manifest = run_pipeline(capped, tmp_path / "capped", data, "smoke", ("adapt", "collect", "translator"),
                                    workers=1)
            break
        except StageStopped as stopped:
            assert "[translator/surface_shpix2pix] stopped by its wall-clock safety cap" in str(stopped)
            stops += 1
    record = next(r for r in manifest["results"] if r["stage"] == "translator/surface_shpix2pix")
    assert stops == 1 and record["metrics"]["epochs"] == 6 and record["ran"]  # 3 steps an epoch: 3 epochs a run
    weights = [load_generator(out / m["models"]["translators"]["surface"]["shpix2pix"])[0].state_dict()
               for out, m in ((tmp_path / "straight", straight), (tmp_path / "capped", manifest))]
    assert all(torch.equal(weights[0][key], weights[1][key]) for key in weights[0])


POOLED = GOOD + """
[profiles.smoke]
jobs = 2
[[profiles.smoke.pool]]
name = "tilt"
contact = "surface"
draws = 2
seed = 1
density_weight = 10.0
pose_weight = 1.0
pose_variables = ["rx_deg"]
[profiles.smoke.posenet]
random_contacts = { surface = 12 }
baselines = ["pix2pix", "sim"]
"""


def test_a_pool_of_generators_and_random_contacts_side_by_side(tmp_path):
    data = tmp_path / "data"
    config = load_config(write_lab(data, rows=30, config=POOLED))
    out = tmp_path / "run"
    manifest = run_pipeline(config, out, data, "smoke", STAGES, workers=1)
    assert manifest["jobs"] == 2
    records = {r["stage"]: r for r in manifest["results"]}
    assert records["collect/random_surface"]["metrics"] == {"rows": 12}
    tilt = json.loads((out / records["translator/surface_tilt"]["folder"] / "run" / "config.json").read_text())
    real = manifest["models"]["posenets"]["models"]["surface"]["real"]
    assert (tilt["pose_net"], tilt["pose_variables"], tilt["seed"]) == (real, ["rx_deg"], 1)  # after the real GDNN
    gdnn = json.loads((out / records["posenet/surface_shpix2pix"]["folder"] / "stage.json").read_text())["key"]
    translators = manifest["models"]["translators"]["surface"]
    assert gdnn["translators"] == [translators["shpix2pix"], translators["tilt"], translators["tilt"]]
    assert gdnn["paired"][-1].startswith("collect/random_surface/")  # the random contacts, translated too
    baseline = json.loads((out / records["posenet/surface_pix2pix"]["folder"] / "stage.json").read_text())["key"]
    assert baseline["translators"] == [translators["pix2pix"]] and baseline["source"] == "pix2pix"
    assert not any(p.startswith("collect/random_") for p in baseline["paired"])  # baselines: the replays only
    evaluation = json.loads((out / manifest["evaluation"]).read_text())
    assert {"real", "shpix2pix", "pix2pix", "sim"} <= set(evaluation["posenet"]["tap"])  # scored side by side
    again = run_pipeline(config, out, data, "smoke", STAGES, workers=1)
    assert not any(result["ran"] for result in again["results"])


def test_a_run_restricted_to_some_contact_types_keeps_their_settings():
    config = load_config(ROOT / "configs" / "tactip331.toml")
    surface = only_contacts(config, ["surface"])
    assert sorted(contacts_of(surface)) == ["surface"] and sorted(surface.datasets) == ["surface_shear", "surface_tap"]
    full, restricted = config.profile("full"), surface.profile("full")
    assert [g.name for g in restricted.pool] == [g.name for g in full.pool if g.contact == "surface"]
    assert full.posenet.random_contacts == {"edge": 10000, "surface": 10000}
    assert restricted.posenet.random_contacts == {"surface": 10000}  # the other types' are dropped
    assert (restricted.translator, restricted.jobs) == (full.translator, full.jobs)  # the cache keys' settings
    assert only_contacts(config, None) is config
    with pytest.raises(ValueError, match="no 'hand' datasets; its contact types: \\['edge', 'surface'\\]"):
        only_contacts(config, ["hand"])


def test_pool_generators_may_differ_in_architecture_and_keep_the_others_settings():
    from simshear_gym.pipelines.config import PoolGenerator, TranslatorStage
    from simshear_gym.pipelines.run import _translator_settings
    from simshear_gym.train.translator_config import TranslatorTrainConfig

    stage = TranslatorStage(contact_epochs={"surface": 26},
                            overrides={"epochs": 14, "decoder_scale": 0.5, "threads": 1})
    plain = _translator_settings(stage, "surface", PoolGenerator("plain", overrides={"seed": 2, "epochs": 10}))
    assert {k: plain[k] for k in ("epochs", "decoder_scale", "seed")} == {"epochs": 10, "decoder_scale": 0.5, "seed": 2}
    assert "shear_decoder" not in plain and "flow_px" not in plain  # unchanged settings: unchanged cache keys
    flow = _translator_settings(stage, "surface", PoolGenerator(
        "flow", overrides={"seed": 3, "flow_px": 32, "lr_schedule": "constant"}))
    assert (flow["flow_px"], flow["lr_schedule"], flow["epochs"]) == (32, "constant", 26)
    wide = _translator_settings(stage, "edge", PoolGenerator(
        "wide", overrides={"decoder_scale": 1.0, "shear_decoder": True}))
    assert (wide["decoder_scale"], wide["shear_decoder"], wide["epochs"]) == (1.0, True, 14)
    for settings in (flow, wide):  # what the step trains with is a valid trainer config
        TranslatorTrainConfig(arch="shpix2pix", paired_dirs=("set",), **settings)
    with pytest.raises(ValueError, match="flow_px must be a power of two"):
        PoolGenerator("bad", overrides={"flow_px": 24})
    with pytest.raises(ValueError, match="lr_schedule must be one of"):
        PoolGenerator("bad", overrides={"lr_schedule": "linear"})


def test_a_contact_types_gdnns_may_train_longer_at_one_budget():
    from simshear_gym.pipelines.config import PosenetStage
    from simshear_gym.train.posenet_config import PosenetTrainConfig

    stage = PosenetStage(contact_epochs={"surface": 60}, overrides={"epochs": 30, "threads": 1})
    surface, edge = stage.train_settings("surface"), stage.train_settings("edge")
    assert (surface["epochs"], edge["epochs"]) == (60, 30)
    unnamed = PosenetStage(overrides={"epochs": 30, "threads": 1})
    assert edge == unnamed.train_settings("edge")  # unnamed types keep their cache keys
    PosenetTrainConfig(source="real", contact="surface", paired_dirs=("set",), **surface)  # a valid trainer config
    with pytest.raises(ValueError, match="contact_epochs must give contact types of .* got \\{'hand': 5\\}"):
        PosenetStage(contact_epochs={"hand": 5})
    cheaper = PosenetStage(contact_epochs={"surface": 60}, baseline_epochs=30, overrides={"epochs": 30, "threads": 1})
    assert cheaper.train_settings("surface") == surface  # the reference and the shipped GDNN keep their key
    assert cheaper.train_settings("surface", baseline=True) == surface | {"epochs": 30}
    assert stage.train_settings("surface", baseline=True) == surface  # absent: the contact type's epochs
    with pytest.raises(ValueError, match="baseline_epochs must be a number of epochs >= 1 or absent, got 0"):
        PosenetStage(baseline_epochs=0)


def test_a_share_of_the_random_contacts_may_be_taps_and_the_shpix2pix_drawn_per_contact(tmp_path):
    from simshear_gym.pipelines.config import ConfigError, PosenetStage

    stage = PosenetStage(random_contacts={"surface": 100}, random_tap_share={"surface": 0.5},
                         translator_draws=2, contact_translator_draws={"surface": 3})
    assert stage.train_settings("surface") == PosenetStage().train_settings("surface")  # the GDNN's key keeps
    assert (stage.translator_draws_for("surface"), stage.translator_draws_for("edge")) == (3, 2)
    with pytest.raises(ValueError, match="contact_translator_draws must give contact types of .* got \\{'edge': 0\\}"):
        PosenetStage(contact_translator_draws={"edge": 0})
    for share in (1.5, -0.1, "half"):
        with pytest.raises(ValueError, match="random_tap_share must give contact types of .* a share in \\[0, 1\\]"):
            PosenetStage(random_tap_share={"surface": share})
    full = load_config(ROOT / "configs" / "tactip331.toml")
    assert set(only_contacts(full, ["edge"]).profile("full").posenet.random_tap_share) <= {"edge"}
    untapped = POOLED.replace("random_contacts = { surface = 12 }", "random_tap_share = { surface = 0.5 }")
    with pytest.raises(ConfigError, match="random_tap_share gives 'surface' a share, but random_contacts draws none"):
        load_config(write_lab(tmp_path, rows=3, config=untapped))


def test_a_pool_generator_may_be_read_by_a_second_real_gdnn(tmp_path):
    from simshear_gym.pipelines.config import PoolGenerator
    from simshear_gym.pipelines.run import training_steps

    second = POOLED.replace('[profiles.smoke.posenet]', """[[profiles.smoke.pool]]
name = "tilt2"
contact = "surface"
seed = 2
pose_weight = 1.0
reader_seed = 1
[profiles.smoke.posenet]""")
    config = load_config(write_lab(tmp_path, config=second))
    profile = config.profile("smoke")
    names = contacts_of(config)
    paired = {name: {"train": f"collect/{name}/train"} for contact in names for name in names[contact]}
    steps = {step.name: step for step in training_steps(config, profile, {}, paired, {}, {"surface": "z_mm"},
                                                        STAGES)}
    assert steps["translator/surface_tilt"].needs == ("posenet/surface_real",)
    assert steps["translator/surface_tilt2"].needs == ("posenet/surface_real_s1",)
    reader = steps["posenet/surface_real_s1"].action
    assert reader.keywords["seed"] == 1 and reader.args[3] == "real"  # the reference's recipe, another seed
    with pytest.raises(ValueError, match="reader_seed 1 needs pose_weight > 0"):
        PoolGenerator("plain", reader_seed=1)
    with pytest.raises(ValueError, match="reader_seed must be an integer >= 0"):
        PoolGenerator("tilt", reader_seed=-1, overrides={"pose_weight": 1.0})


def test_a_pool_generator_may_start_from_another_translators_weights(tmp_path):
    from simshear_gym.pipelines.config import PoolGenerator, Profile, TranslatorStage
    from simshear_gym.pipelines.run import training_steps

    tuned = POOLED.replace('[profiles.smoke.posenet]', """[[profiles.smoke.pool]]
name = "tuned"
contact = "surface"
start_from = "shpix2pix"
pose_weight = 1.0
[[profiles.smoke.pool]]
name = "tuned2"
start_from = "tuned"
[profiles.smoke.posenet]""")
    with pytest.raises(ValueError, match="starts from 'tuned', trained for surface contacts only"):
        load_config(write_lab(tmp_path, config=tuned))  # tuned2 trains for every contact type
    surface_only = tuned.replace('name = "tuned2"', 'name = "tuned2"\ncontact = "surface"')
    config = load_config(write_lab(tmp_path, config=surface_only))
    names = contacts_of(config)
    paired = {name: {"train": f"collect/{name}/train"} for contact in names for name in names[contact]}
    steps = {step.name: step for step in training_steps(config, config.profile("smoke"), {}, paired, {},
                                                        {"surface": "z_mm"}, STAGES)}
    assert steps["translator/surface_tuned"].needs == ("posenet/surface_real", "translator/surface_shpix2pix")
    assert steps["translator/surface_tuned2"].needs == ("translator/surface_tuned",)
    with pytest.raises(ValueError, match="start_from names the generator itself"):
        PoolGenerator("tuned", start_from="tuned")
    for pool in ((PoolGenerator("a", start_from="b"), PoolGenerator("b", start_from="a")),
                 (PoolGenerator("a", start_from="missing"),)):
        with pytest.raises(ValueError, match="must be 'shpix2pix' or another pool generator's name, without a loop"):
            Profile(pool=pool)
    with pytest.raises(ValueError, match=r"'wide' starts from 'shpix2pix', another architecture .*'decoder_scale': "
                                         r"\(1.0, 0.5\)"):
        Profile(translator=TranslatorStage(overrides={"decoder_scale": 0.5}),
                pool=(PoolGenerator("wide", start_from="shpix2pix", overrides={"decoder_scale": 1.0}),))


def test_a_fine_tuned_pool_generator_trains_from_the_shpix2pix_it_names(tmp_path):
    data = tmp_path / "data"
    tuned = GOOD + """
[[profiles.smoke.pool]]
name = "tuned"
contact = "surface"
start_from = "shpix2pix"
"""
    config = load_config(write_lab(data, rows=12, config=tuned))
    out = tmp_path / "run"
    manifest = run_pipeline(config, out, data, "smoke", ("adapt", "collect", "translator"), workers=1)
    translators = manifest["models"]["translators"]["surface"]
    records = {r["stage"]: r for r in manifest["results"]}
    run = json.loads((out / records["translator/surface_tuned"]["folder"] / "run" / "config.json").read_text())
    assert run["init_weights"] == translators["shpix2pix"]  # relative to the run folder, as the stage key
    key = json.loads((out / records["translator/surface_tuned"]["folder"] / "stage.json").read_text())["key"]
    assert key["settings"]["init_weights"] == translators["shpix2pix"]


def test_stages_need_the_ones_before_them(tmp_path):
    config = load_config(write_lab(tmp_path))
    with pytest.raises(ValueError, match=r"need the stages before them too: add \['collect'\]"):
        run_pipeline(config, tmp_path / "run", tmp_path, "smoke", ("adapt", "translator"))


@pytest.mark.data
def test_example_lab_smoke_trains_from_its_config_alone(data_root, tmp_path):
    make_example(data_root, tmp_path / "lab", rows_per_split=48)
    config = load_config(ROOT / "configs" / "example_lab.toml")
    manifest = run_pipeline(config, tmp_path / "run", tmp_path / "lab", "smoke", STAGES, workers=1)
    evaluation = json.loads((tmp_path / "run" / manifest["evaluation"]).read_text())
    assert set(evaluation["posenet"]["surface_tap"]["shpix2pix"]) == {"z_mm", "rx_deg", "ry_deg", "mean_nll"}


def test_a_sensor_without_a_pipeline_run_says_how_to_make_one(tmp_path):
    from simshear_gym.models.zoo import load_sensor

    with pytest.raises(FileNotFoundError, match="run `simshear pipeline run CONFIG` first"):
        load_sensor(tmp_path)
    (tmp_path / "sensor.json").write_text('{"sensor": "lab"}')
    with pytest.raises(ValueError, match="not a sensor file"):
        load_sensor(tmp_path / "sensor.json")


def test_the_runs_variable_sets_come_from_the_gdnns_codec(monkeypatch):
    """A contact type's variables: the named set where the data vary as it does (the edge's Rz as its angle), else
    the inline spec the GDNN's codec writes (ranges to 6 digits, a wide angle periodic); each set read once."""
    from types import SimpleNamespace

    import pandas as pd

    from simshear_gym.data.adapter import CANONICAL_COLUMNS
    from simshear_gym.models.gdnn import variable_set
    from simshear_gym.pipelines import run

    def table(**columns):
        rows = {column: [0.0, 0.0] for column in CANONICAL_COLUMNS.values()}
        rows.update({CANONICAL_COLUMNS[name]: values for name, values in columns.items()})
        return pd.DataFrame(rows)

    tables = {"edge/train": table(pose_y=[-5.0, 5.0], pose_z=[3.0, 4.0], pose_rz=[-179.0, 179.0], move_x=[0.0, 1.0],
                                  move_y=[1.0, 0.0], move_rz=[2.0, 0.0]),
              "edge/val": table(pose_y=[-4.0, 4.0], pose_z=[3.5, 4.5], pose_rz=[0.0, 10.0]),
              "shear/train": table(pose_z=[3.0, 4.123456789], move_x=[-1.0, 2.0], move_rz=[0.0, -3.0]),
              "shear/val": table(pose_z=[3.2, 3.3])}
    reads = []
    monkeypatch.setattr(run, "read_set", lambda path: reads.append(path.name) or SimpleNamespace(
        targets=tables[f"{path.parent.name}/{path.name}"]))
    config = SimpleNamespace(datasets={"edge": SimpleNamespace(contact="edge", kind="shear"),
                                       "shear": SimpleNamespace(contact="surface", kind="shear")})
    adapted = {name: {split: f"{name}/{split}" for split in ("train", "val")} for name in config.datasets}
    root = Path("/nowhere")
    assert run.variables_for(config, ["edge"], adapted, root) == "edge"
    assert sorted(reads) == ["train", "val"]
    spec = run.variables_for(config, ["shear"], adapted, root)
    assert spec == ("z_mm:pose_3:3:4.12346,shear_x_mm:shear_sensor_x_mm:-3:3,"
                    "shear_rz_deg:shear_sensor_rz_deg:-3:3")
    assert [v.name for v in variable_set(spec).variables] == ["z_mm", "shear_x_mm", "shear_rz_deg"]
    reads.clear()
    assert run.label_ranges(config, ["edge"], adapted, root) == {
        "pose_2": [-5.0, 5.0], "pose_3": [3.0, 4.0], "pose_6": [-179.0, 179.0], "move_1": [0.0, 1.0],
        "move_2": [0.0, 1.0], "move_6": [0.0, 2.0]}
    assert reads == ["train"]
