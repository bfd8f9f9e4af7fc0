"""A stopped ``simshear pipeline run`` stops all of its processes and stays resumable (issue 41, item 5).

The run goes in its own session, so every process it starts (the step graph's worker processes, multiprocessing's
helper) is found by its session id in ``/proc``, whatever became of its parent.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from simshear_gym.pipelines.stages import RunStopped, end_children, stop_on_signals
from tests.test_pipeline_check import write_lab

ROOT = Path(__file__).resolve().parents[1]
STEP_STARTED = re.compile(r"^\[(translator|posenet)/\S+\] (running|resuming) in ")


def session_processes(session: int) -> list[int]:
    """The live (not zombie) processes of a session, from /proc."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) ": state, ppid, pgrp, session, ...
        if int(fields[3]) == session and fields[0] != "Z":
            found.append(int(entry.name))
    return found


def wait_until_gone(session: int, seconds: float) -> list[int]:
    """The session's processes left after waiting up to ``seconds`` for them to end."""
    deadline = time.monotonic() + seconds
    left = session_processes(session)
    while left and time.monotonic() < deadline:
        time.sleep(0.2)
        left = session_processes(session)
    return left


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_mid_stage_ends_every_process_and_the_rerun_resumes(tmp_path, signum):
    data = tmp_path / "lab"
    config = write_lab(data, rows=30)
    out = tmp_path / "run"
    argv = [sys.executable, "-m", "simshear_gym.cli", "pipeline", "run", str(config), "--profile", "smoke", "--jobs",
            "2", "--workers", "1", "--data", str(data), "--out", str(out)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    process = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               start_new_session=True)
    output = []
    try:
        for line in process.stdout:  # until a training step runs in a worker (or the run ends: EOF)
            output.append(line)
            if STEP_STARTED.match(line):
                break
        assert STEP_STARTED.match(output[-1]), "".join(output)
        workers = [pid for pid in session_processes(process.pid) if pid != process.pid]
        assert len(workers) >= 2, workers  # the step graph's worker processes are running
        os.kill(process.pid, signum)
        output += process.stdout.readlines()
        process.wait(timeout=60)
        left = wait_until_gone(process.pid, 10.0)
    finally:
        if process.poll() is None:
            process.kill()
        for pid in session_processes(process.pid):  # never leave a process behind, even when the test fails
            os.kill(pid, signal.SIGKILL)
    assert left == [], f"processes of the stopped run still alive after 10 s: {left}"
    assert process.returncode == 128 + signum, "".join(output)
    errors = [line for line in output if line.startswith("simshear: error:")]
    assert len(errors) == 1 and f"stopped by {signal.Signals(signum).name}" in errors[0], "".join(output)
    assert "Traceback" not in "".join(output)
    assert not (out / "manifest.json").exists()

    rerun = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)
    assert rerun.returncode == 0, rerun.stdout[-3000:] + rerun.stderr[-3000:]
    manifest = json.loads((out / "manifest.json").read_text())
    ran = {result["stage"]: result["ran"] for result in manifest["results"]}
    assert not ran["adapt/tap"] and not ran["collect/tap"]  # finished before the signal: cached
    assert manifest["evaluation"] and (out / manifest["evaluation"]).is_file()


def test_the_signal_handlers_raise_once_and_are_put_back():
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(RunStopped) as stopped:
        with stop_on_signals():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler interrupts this at once
    assert stopped.value.signum == signal.SIGTERM and "rerun the same command to resume" in str(stopped.value)
    assert signal.getsignal(signal.SIGTERM) is before
    assert end_children() == 0  # this process started no worker
