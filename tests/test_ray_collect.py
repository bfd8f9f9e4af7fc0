"""Collection on Ray and in plain processes: the same rows, byte for byte, whatever the executor and the number
of workers; a clear error when the ray extra is missing."""

import hashlib
import sys
from pathlib import Path

import numpy as np
import pytest

from simshear_gym.cli import main
from simshear_gym.sim.collect import CollectConfig, random_set, replay_set
from simshear_gym.sim.parallel import RAY_EXTRA, ExecutorError, map_chunks, ray_session
from simshear_gym.sim.replay import render_poses
from tests.test_collect import real_subset


def digest(directory: Path) -> dict[str, str]:
    """sha256 of every file of a set (images, targets.csv, meta.json), by relative path."""
    return {str(path.relative_to(directory)): hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(directory.rglob("*")) if path.is_file()}


def test_plain_random_rows_do_not_depend_on_worker_count(tmp_path):
    sets = {}
    for workers in (1, 3):
        out = tmp_path / f"w{workers}"
        assert random_set("surface", 10, seed=5, out_dir=out, config=CollectConfig(workers=workers)) == 10
        sets[workers] = digest(out)
    assert len(sets[1]) == 12 and sets[1] == sets[3]  # 10 images, targets.csv, meta.json


@pytest.mark.data
def test_plain_replay_rows_do_not_depend_on_worker_count(data_root, tmp_path):
    real_dir = real_subset(data_root, tmp_path, "edge", rows=7)
    for workers in (1, 2):
        replay_set(real_dir, tmp_path / f"w{workers}", CollectConfig(workers=workers), root=tmp_path)
    assert digest(tmp_path / "w1") == digest(tmp_path / "w2")


def test_map_chunks_keeps_the_order_of_the_chunks():
    assert map_chunks(abs, [-3, -1, -2, -5], workers=3) == [3, 1, 2, 5]
    assert map_chunks(abs, [], workers=2) == []


def test_missing_ray_names_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    with pytest.raises(ExecutorError, match=r'pip install -e "\.\[ray\]"'):
        map_chunks(abs, [-1], workers=1, ray_address="local")
    assert RAY_EXTRA == 'pip install -e ".[ray]"'


def test_bad_ray_address_is_refused(tmp_path, capsys):
    with pytest.raises(ValueError, match="ray address"):
        CollectConfig(ray_address=" ")
    assert main(["collect", "--task", "edge", "--n", "2", "--out", str(tmp_path / "o"), "--ray", "a b"]) == 2
    assert "expected 'local', 'auto'" in capsys.readouterr().err


@pytest.fixture(scope="module")
def local_ray():
    """A local Ray with two CPUs for the module's tests (the code under test uses it and leaves it running)."""
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False)
    yield ray
    ray.shutdown()


@pytest.mark.slow  # starting a local Ray takes 5 to 15 s
def test_local_ray_rows_equal_plain_rows(local_ray, tmp_path, capsys):
    plain, on_ray = tmp_path / "plain", tmp_path / "ray"
    random_set("edge", 9, seed=2, out_dir=plain, config=CollectConfig(workers=1))
    random_set("edge", 9, seed=2, out_dir=on_ray, config=CollectConfig(workers=2, ray_address="local"))
    assert digest(on_ray) == digest(plain)
    # the command line, on the same (running) Ray
    assert main(["collect", "--task", "edge", "--n", "9", "--seed", "2", "--out", str(tmp_path / "cli"),
                 "--workers", "2", "--ray", "local"]) == 0
    assert "wrote 9 paired rows" in capsys.readouterr().out
    assert digest(tmp_path / "cli") == digest(plain)
    assert local_ray.is_initialized()  # a session the caller started is left running
    # renders and the order of the chunks
    poses = np.array([[0.0, 0.0, 3.5, 0.0, 0.0, a] for a in range(-20, 21, 8)])
    np.testing.assert_array_equal(render_poses("surface", poses, workers=3, ray_address="auto"),
                                  render_poses("surface", poses, workers=1))
    assert map_chunks(abs, [-3, -1, -2], workers=2, ray_address="local") == [3, 1, 2]
    with ray_session("local") as ray:
        assert ray is local_ray


def _signal_handlers(_chunk) -> tuple[bool, bool]:
    import signal

    return signal.getsignal(signal.SIGTERM) is signal.SIG_DFL, signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_pool_workers_do_not_inherit_a_commands_stop_handlers():
    """A forked worker with the command's SIGTERM handler printed a RunStopped traceback when its pool ended it."""
    from simshear_gym.pipelines.stages import stop_on_signals

    with stop_on_signals():
        assert map_chunks(_signal_handlers, [0, 1], workers=2) == [(True, True), (True, True)]
