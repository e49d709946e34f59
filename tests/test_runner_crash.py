"""A run killed with SIGKILL mid-run leaves a log whose completed trials replay, and --resume finishes it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rig.log.reading.reader import read_run
from rig.runner.journal import RunJournal

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
@pytest.mark.subprocess
def test_sigkill_mid_run_then_resume(tmp_path):
    protocol = ROOT / "protocols" / "joint_estimation.yaml"
    journal_path = tmp_path / "k1.journal.json"
    cmd = [
        sys.executable,
        "-m",
        "rig.cli",
        "run",
        str(protocol),
        "--out",
        str(tmp_path),
        "--run-id",
        "k1",
        "--json",
    ]
    err_path = tmp_path / "stderr.txt"
    with err_path.open("w") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT)
    try:
        deadline = time.monotonic() + 120
        done = 0
        while time.monotonic() < deadline and proc.poll() is None:
            if journal_path.exists():
                done = len(RunJournal.load(journal_path).completed)
                if done >= 3:
                    break
            time.sleep(0.05)
        assert proc.poll() is None, err_path.read_text()
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    journal = RunJournal.load(journal_path)
    assert journal.status == "running" and len(journal.completed) >= 3

    log = read_run(tmp_path / "k1.mcap")
    assert not log.complete and log.warnings
    results = log.topic("/rig/trial/result")
    # Every journalled trial was flushed to the log before the journal recorded it.
    assert set(journal.completed_ids) <= set(results["trial_id"])

    resumed = subprocess.run(
        [*cmd[:-3], "--resume", "k1", "--json"], capture_output=True, text=True, cwd=ROOT, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr
    report = json.loads(resumed.stdout)
    ids = [t["trial_id"] for t in report["trials"]]
    assert sorted(ids) == list(range(1, 25)) and len(ids) == 24
    assert report["completed"] == 24 and len(report["logs"]) == 2
    combined = read_run([tmp_path / "k1.mcap", tmp_path / "k1.part2.mcap"])
    assert set(range(1, 25)) <= set(combined.topic("/rig/trial/result")["trial_id"])
