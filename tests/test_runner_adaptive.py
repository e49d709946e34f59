"""Adaptive joint-estimation blocks in the runner, on the object-level simulated rig (tests/runner_rig.py).

The world's specimen slips at its capacity over the distance times a factor each trial draws (the
built-in simulated rig: multiplicative scatter), so the planner's choices can be followed and a
resumed run compared with an uninterrupted one.
"""

from __future__ import annotations

import json

import pytest
from mcap.reader import make_reader

from rig.log.format import schemas
from rig.runner.execute import RunRequest, prepare_run
from rig.runner.journal import RunJournal
from rig.runner.progress import SilentProgress
from tests.helpers import QUICK_STEPS, adaptive_block, quick_protocol
from tests.runner_rig import execute_on, runner_rig

MAX_SLIP_FORCE_N = 0.8 * 70.0  # max_force_fraction x max_force_n


def adaptive_protocol(target: float, max_trials: int) -> str:
    """QUICK_PROTOCOL's settings, its block adaptive (8 candidates, at least 6 trials, the weighted fit)."""
    block = adaptive_block(
        distance_count=8,
        max_trials=max_trials,
        min_trials=6,
        target_half_width_rel=target,
        estimator="weighted",
        steps=QUICK_STEPS,
    )
    return quick_protocol(name="adaptive", blocks=[block])


class RecordingProgress(SilentProgress):
    """Keeps the progress display's one-line messages."""

    def __init__(self) -> None:
        self.messages: list[str] = []

    def message(self, text: str) -> None:
        self.messages.append(text)


@pytest.fixture
def run_adaptive(tmp_path, protocol_file):
    """`run_adaptive(target=, max_trials=, run_id=, resume=, interrupt_at_trial=)` -> (report, progress)."""

    def run(*, target=0.001, max_trials=8, run_id="a1", resume=False, interrupt_at_trial=None):
        protocol = protocol_file(adaptive_protocol(target, max_trials), name=f"{run_id}.yaml")
        request = RunRequest(
            protocol_path=protocol,
            rig_path=None,
            out_dir=tmp_path / "out",
            seed=1,
            run_id=None if resume else run_id,
            resume=run_id if resume else None,
        )
        progress = RecordingProgress()
        prepared = prepare_run(request)
        return execute_on(
            prepared, runner_rig(prepared, interrupt_at_trial=interrupt_at_trial), progress
        ), progress

    return run


def log_messages(path) -> list[str]:
    with open(path, "rb") as f:
        return [
            json.loads(message.data)["message"]
            for _, channel, message in make_reader(f).iter_messages()
            if channel.topic == schemas.LOG
        ]


@pytest.mark.slow  # whole runs of 6-16 trials on the object-level simulated rig: 1-5 s
def test_the_planner_chooses_every_trial_and_stops_on_the_budget(run_adaptive, tmp_path):
    report, progress = run_adaptive()
    assert report.exit_code == 0 and not report.aborted and report.completed == 8 and report.planned == 8
    distances = [t.distance_m for t in report.trials]
    assert distances[:2] == [0.25, 0.155714286]  # the start-up, longest first
    assert distances[2] < 0.155714286  # its third trial: the shortest distance found safe
    assert all(t.outcome == "slip" for t in report.trials)
    # Never a slip force above the planner's limit.
    assert max(t.peak_force_n for t in report.trials) < MAX_SLIP_FORCE_N
    assert [t.repeat for t in report.trials] == [1 + distances[:i].count(d) for i, d in enumerate(distances)]
    # Proportional scatter (the weighted estimator's model): the planner spreads over the range.
    assert len(set(distances)) >= 6
    (design,) = report.design
    data = report.as_json()["design"][0]
    assert data["stop_reason"] == "budget" and data["trials"] == 8 and data["estimator"] == "weighted"
    assert data["scatter_model"] == "multiplicative"
    # Replicated distances: the pure-error F test; all distinct: the offset t test.
    expected_test = "offset_t" if len(set(distances)) == len(distances) else "pure_error_f"
    assert data["lack_of_fit"]["test"] == expected_test and data["lack_of_fit"]["rejected"] is False
    assert design.step.stop is not None
    # Reported after every trial, on the progress display and in the log; the last says why it stopped.
    reports = [m for m in progress.messages if m.startswith("adaptive design")]
    assert len(reports) == 9 and "stopped after 8 trial(s): trial budget of 8 used" in reports[-1]
    assert all("lack of fit" in m for m in reports)
    logged = [m for m in log_messages(tmp_path / "out" / "a1.mcap") if m.startswith("adaptive design")]
    assert logged == reports
    journal = RunJournal.load(tmp_path / "out" / "a1.journal.json")
    assert journal.planned_trials == list(range(1, 9)) and journal.status == "completed"


@pytest.mark.slow  # whole runs of 6-16 trials on the object-level simulated rig: 1-5 s
def test_the_block_stops_when_the_target_is_reached(run_adaptive):
    report, progress = run_adaptive(target=0.5, max_trials=20)
    assert report.exit_code == 0 and report.completed == 6 and report.planned == 20  # min_trials
    assert report.as_json()["design"][0]["stop_reason"] == "target_reached"
    assert "target reached" in progress.messages[-1]
    assert report.as_json()["design"][0]["half_width_rel"] <= 0.5


@pytest.mark.slow  # whole runs of 6-16 trials on the object-level simulated rig: 1-5 s
def test_a_resumed_adaptive_run_replans_from_its_journal(run_adaptive, tmp_path):
    whole, _ = run_adaptive(run_id="whole")
    interrupted, _ = run_adaptive(run_id="part", interrupt_at_trial=5)
    assert interrupted.exit_code == 130 and interrupted.completed == 4
    resumed, progress = run_adaptive(run_id="part", resume=True)
    assert resumed.exit_code == 0 and resumed.completed == 8
    assert [t.trial_id for t in resumed.trials] == list(range(1, 9))
    # Trials 1-4 come from the journal and trial 5 is planned from them, as in the uninterrupted run
    # (the same world drew trials 1-4); the resumed world draws its own trials from there on.
    assert [t.distance_m for t in resumed.trials[:5]] == [t.distance_m for t in whole.trials[:5]]
    assert "after 4 trial(s)" in next(m for m in progress.messages if m.startswith("adaptive design"))
    # Resuming a run whose adaptive block already stopped: it stops again at once, nothing runs.
    journal = RunJournal.load(tmp_path / "out" / "part.journal.json")
    journal.status = "interrupted"
    journal.save()
    again, progress = run_adaptive(run_id="part", resume=True)
    assert again.exit_code == 0 and again.completed == 8
    assert next(m for m in progress.messages if m.startswith("adaptive design")).startswith(
        "adaptive design, block 0 (joint 1): stopped after 8 trial(s)"
    )
