"""Option errors come before the heavy imports: each bad command line below is answered with one ``simshear:
error:`` line by a process that never imported torch or PyBullet (checked in that process's ``sys.modules``, not
by timing it); a config's missing data root names the config's own files."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "pybullet", "stable_baselines3")

PROBE = f"""
import json, sys
from simshear_gym.cli import main
code = main(sys.argv[1:])
print(json.dumps({{"code": code, "heavy": [name for name in {HEAVY!r} if name in sys.modules]}}))
"""


def answer(*words: str) -> tuple[dict, str]:
    """(the exit code and the heavy modules the command's process imported, its stderr)."""
    done = subprocess.run([sys.executable, "-c", PROBE, *words], capture_output=True, text=True, timeout=300,
                          cwd=REPO)
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


@pytest.mark.parametrize(("words", "message"), [
    (("evaluate", "servo", "--variants", "ppo"), "--variants ppo needs --policy-ppo MODEL.zip"),
    (("evaluate", "servo", "--variants", "pix2pix"), "--variants pix2pix needs --posenet-pix2pix"),
    (("evaluate", "servo", "--variants", "policy", "--policy", "no/such/model.zip"), "no such model file"),
    (("evaluate", "posenet", "--model", "surface=shipped"), "give --contact"),
    (("evaluate", "real-cycle", "--cycles", "1"), "--cycles must be >= 10"),
    (("train", "rl", "--out", "unused", "--timesteps", "0"), "0 allowed with --bc-steps"),
    (("train", "rl", "--out", "unused", "--preset", "tracking-first", "--bc-noise", "2"), "bc_noise in (0, 1]"),
])
def test_option_errors_come_before_torch_and_pybullet(words, message):
    result, stderr = answer(*words)
    assert result == {"code": 2, "heavy": []}, stderr
    lines = [line for line in stderr.splitlines() if line.startswith("simshear: error:")]
    assert len(lines) == 1 and message in lines[0], stderr


def test_a_missing_data_root_names_the_configs_own_files(tmp_path):
    missing = tmp_path / "no-such-root"
    done = subprocess.run([sys.executable, "-m", "simshear_gym.cli", "pipeline", "check", "configs/example_lab.toml",
                           "--data", str(missing)], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert done.returncode == 2
    assert ("to the folder holding labels.csv and frames/ (configs/example_lab.toml's datasets)"
            in done.stderr), done.stderr
    assert "tactip331" not in done.stderr


def test_config_files_lists_the_top_entries_of_relative_paths():
    from simshear_gym.data.adapter import DataFile, config_files

    class Dataset:  # the one attribute config_files reads
        def __init__(self, *files):
            self.files = files

    assert config_files([Dataset(DataFile("labels.csv", "frames"))]) == "labels.csv and frames/"
    assert config_files([Dataset(DataFile("tactip331/a/targets.csv", "tactip331/a/images")),
                         Dataset(DataFile("/abs/x.csv", "/abs/images"))], "c.toml") == "tactip331/ (c.toml's datasets)"
