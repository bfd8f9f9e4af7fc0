"""``--wandb PROJECT`` on the trainers: a W&B run mirroring the tensorboard logs, or one line without wandb."""

from __future__ import annotations

import sys
import types

from simshear_gym.train.wandb_sync import MISSING, RUN_ID_FILE, wandb_run


class FakeRun:
    def __init__(self, calls: list) -> None:
        self.calls = calls

    def finish(self) -> None:
        self.calls.append(("finish",))


def fake_wandb(calls: list) -> types.ModuleType:
    module = types.ModuleType("wandb")

    def init(**kwargs):
        calls.append(("init", kwargs))
        return FakeRun(calls)

    module.init = init
    return module


def test_no_project_no_run(tmp_path, capsys):
    with wandb_run(None, tmp_path, {"epochs": 3}) as run:
        assert run is None
    assert capsys.readouterr().out == "" and not (tmp_path / RUN_ID_FILE).exists()


def test_without_wandb_one_line_and_tensorboard_only(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "wandb", None)  # import wandb raises ImportError
    with wandb_run("lab", tmp_path, {"epochs": 3}) as run:
        assert run is None
    assert capsys.readouterr().out.strip() == MISSING


def test_a_run_mirrors_tensorboard_with_the_config_and_a_resume_continues_it(tmp_path, monkeypatch):
    calls: list = []
    monkeypatch.setitem(sys.modules, "wandb", fake_wandb(calls))
    with wandb_run("lab", tmp_path / "run", {"epochs": 3}):
        pass
    (_, first), finish = calls
    assert finish == ("finish",)
    assert first["project"] == "lab" and first["sync_tensorboard"] is True and first["config"] == {"epochs": 3}
    assert first["name"] == "run" and first["resume"] == "allow"
    with wandb_run("lab", tmp_path / "run", {"epochs": 5}):
        pass
    assert calls[2][1]["id"] == first["id"] == (tmp_path / "run" / RUN_ID_FILE).read_text().strip()


def test_train_rl_takes_the_flag(tmp_path, capsys, monkeypatch):
    from simshear_gym import cli

    monkeypatch.setitem(sys.modules, "wandb", None)
    code = cli.main(["train", "rl", "--out", str(tmp_path / "rl"), "--timesteps", "16", "--n-steps", "16",
                     "--batch-size", "16", "--n-epochs", "1", "--checkpoint-steps", "16", "--quiet", "--wandb",
                     "lab"])
    assert code == 0 and MISSING in capsys.readouterr().out
    assert (tmp_path / "rl" / "model.pt").is_file()
