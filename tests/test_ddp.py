"""Data-parallel training under torchrun: two CPU processes (gloo) train the GDNN and the translator for a few
steps; the run directory is what one process writes, and the checkpoint resumes in one process and again in two."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch

from simshear_gym.cli import main
from simshear_gym.models.posenet_io import load_posenet
from simshear_gym.models.translator import Translator
from simshear_gym.train.distributed import Distributed, torchrun_place
from tests.test_train_loop import _paired_set_on_disk

COMMON = ["--holdout", "0.2", "--threads", "1", "--batch-size", "8", "--device", "cpu"]
COMMANDS = {
    "posenet": ["train", "posenet", "--source", "sim", "--contact", "surface", "--image-size", "16", *COMMON],
    # a discriminator too (two forward passes per step through its DistributedDataParallel); it needs 32 px
    "translator": ["train", "translator", "--arch", "shpix2pix", "--image-size", "32", "--base-channels", "2",
                   "--max-channels", "4", "--gan-weight", "1", *COMMON],
}
WEIGHTS = {"posenet": "model", "translator": "generator"}


def test_torchrun_place_reads_the_environment():
    assert torchrun_place({}) is None
    assert torchrun_place({"RANK": "0", "WORLD_SIZE": "1", "LOCAL_RANK": "0"}) is None  # one process: as ever
    assert torchrun_place({"RANK": "1", "WORLD_SIZE": "2", "LOCAL_RANK": "1"}) == (1, 2, 1)
    with pytest.raises(ValueError, match=r"WORLD_SIZE=2 but \['LOCAL_RANK'\] unset"):
        torchrun_place({"RANK": "1", "WORLD_SIZE": "2"})


def test_each_process_takes_its_share_of_every_batch():
    shares = [Distributed(rank, 2, torch.device("cpu")).rows(7) for rank in (0, 1)]
    assert shares == [[0, 2, 4, 6], [1, 3, 5, 0]]  # every row, padded to equal shares
    assert Distributed(0, 2, torch.device("cpu")).min_batch_rows() == 3  # two rows per process


def _torchrun(args: list[str], tmp_path) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "SIMSHEAR_CACHE": str(tmp_path / "cache")}
    result = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                             "-m", "simshear_gym.cli", *args], env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result


def _checkpoint(run_dir) -> dict:
    return torch.load(run_dir / "checkpoint.pt", map_location="cpu", weights_only=False)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["posenet", "translator"])
def test_two_processes_write_one_processes_run_directory_and_resume_either_way(tmp_path, name):
    paired = str(_paired_set_on_disk(tmp_path / "sets", n=24, size=32))
    command = [*COMMANDS[name], "--paired", paired]
    two, one = tmp_path / "two", tmp_path / "one"

    result = _torchrun([*command, "--epochs", "1", "--out", str(two)], tmp_path)
    summaries = [line for line in result.stdout.splitlines() if line.startswith("{")]
    assert len(summaries) == 1  # rank 0 alone prints
    assert main([*command, "--epochs", "1", "--out", str(one)]) == 0
    assert sorted(path.name for path in two.iterdir()) == sorted(path.name for path in one.iterdir())
    distributed, single = _checkpoint(two), _checkpoint(one)
    assert distributed.keys() == single.keys()
    weights = distributed[WEIGHTS[name]]["state_dict"]
    assert weights.keys() == single[WEIGHTS[name]]["state_dict"].keys()
    assert not any(key.startswith("module.") for key in weights)
    assert distributed["step"] == single["step"] == 3  # 19 training rows: batches of 8, 8 and 3
    assert distributed["config"] == single["config"]

    assert main([*command, "--epochs", "2", "--out", str(two), "--resume"]) == 0  # one process goes on
    _torchrun([*command, "--epochs", "3", "--out", str(two), "--resume"], tmp_path)  # and two again
    history = json.loads((two / "history.json").read_text())["epochs"]
    assert [record["epoch"] for record in history] == [1, 2, 3] and _checkpoint(two)["step"] == 9
    if name == "posenet":
        model, card = load_posenet(two / "best.pt")
        assert card["source"] == "sim" and model(torch.rand(2, 1, 16, 16))[0].shape == (2, 6)
    else:
        translator = Translator.load(two / "best.pt")
        assert translator(torch.zeros(2, 32, 32, dtype=torch.uint8).numpy(), torch.zeros(2, 6).numpy()).shape == (
            2, 32, 32)
