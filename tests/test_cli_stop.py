"""Any ``simshear`` command stopped by SIGTERM or SIGINT runs its ``finally`` blocks and ends the worker processes
it started (exit status 128 + the signal), not only ``pipeline run`` (tests/test_pipeline_stop.py)."""

from __future__ import annotations

import importlib
import multiprocessing
import os
import signal
import subprocess
import sys
import time
import types

import pytest

from tests.test_pipeline_stop import session_processes, wait_until_gone


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_runs_the_commands_finally_and_ends_its_workers(monkeypatch, capsys, signum):
    from simshear_gym import cli

    seen: dict[str, object] = {}

    def run(args) -> int:
        child = multiprocessing.get_context("fork").Process(target=time.sleep, args=(60.0,), daemon=False)
        child.start()
        seen["child"] = child
        try:
            os.kill(os.getpid(), signum)
            time.sleep(30.0)  # the handler raises before this ends
            seen["slept"] = True
        finally:
            seen["finally"] = True
        return 0

    command = types.SimpleNamespace(run=run, add_arguments=lambda parser: None)
    monkeypatch.setattr(cli, "importlib", types.SimpleNamespace(
        import_module=lambda name: command if name == "simshear_gym.demo" else importlib.import_module(name)))
    # what the handlers are before (a shell's background job starts with SIGINT ignored, a terminal's not)
    before = {number: signal.getsignal(number) for number in (signal.SIGTERM, signal.SIGINT)}
    started = time.monotonic()
    assert cli.main(["demo"]) == 128 + signum
    assert seen["finally"] and "slept" not in seen and time.monotonic() - started < 30.0
    assert not seen["child"].is_alive()
    name = signal.Signals(signum).name
    assert f"simshear: stopped by {name}; 1 worker process ended" in capsys.readouterr().err
    assert {number: signal.getsignal(number) for number in before} == before  # the handlers are put back


@pytest.mark.slow
def test_sigterm_to_a_vectorised_benchmark_leaves_no_process(tmp_path):
    """``evaluate env-speed`` with two vector-env workers: SIGTERM once the workers run; nothing of it is left 10 s
    later."""
    argv = [sys.executable, "-m", "simshear_gym.cli", "evaluate", "env-speed", "--steps", "10", "--vector-steps",
            "1000000", "--num-envs", "2", "--workers", "2", "--threads", "1", "--runtimes", "onnx", "--onnx-threads",
            "1", "--vector-runtimes", "onnx", "--out", str(tmp_path)]
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    try:
        deadline = time.monotonic() + 300.0
        while len(session_processes(process.pid)) < 3 and process.poll() is None:  # the main one and 2 workers
            assert time.monotonic() < deadline, "the vectorised run's workers never started"
            time.sleep(0.2)
        assert process.poll() is None, process.communicate()
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=60)
        assert process.returncode == 128 + signal.SIGTERM, err[-2000:]
        assert "stopped by SIGTERM" in err
        assert wait_until_gone(process.pid, 10.0) == []
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
