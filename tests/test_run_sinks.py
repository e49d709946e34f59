"""One run path: a run emits to sinks it does not know; `rig run` validates once; a study seed is a run."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from rig.errors import InputError
from rig.hw.seams import LoadCellSample, ServoState
from rig.log.format import schemas
from rig.records import Estimate, LogLevel, LogMessage, TrialResult
from rig.rigs import open_rig
from rig.runner import execute as run_module
from rig.runner.execute import RunReport, RunRequest, claim_run, execute_run, prepare_run, validate_run
from rig.runner.sinks import NullSink
from rig.sim.kinds import DeviceLevel
from rig.study import worker
from rig.study.worker import StudySpec, run_seed
from rig.vocabulary import ServoRole

ROOT = Path(__file__).resolve().parent.parent
SMOKE = ROOT / "protocols" / "smoke.yaml"


class RecordingSink(NullSink):
    """Keeps what it is given, in order (the tick rows as counts of samples and states)."""

    def __init__(self, *, wants_ticks: bool, note: str | None = None) -> None:
        self.wants_ticks = wants_ticks
        self.note = note
        self.events: list[tuple[Any, ...]] = []

    def start(self, run_id: str, total: int, done: int) -> None:
        self.events.append(("start", run_id, total, done))

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        self.events.append(("metadata", name))

    def attachment(self, name: str, media_type: str, data: bytes) -> None:
        self.events.append(("attachment", name))

    def log(self, topic: str, time_ns: int, payload: Mapping[str, Any]) -> None:
        self.events.append(("log", topic))

    def tick_rows(
        self,
        samples: list[LoadCellSample],
        states: Mapping[int, ServoState],
        roles: Mapping[int, ServoRole],
    ) -> None:
        self.events.append(("ticks", len(samples), len(states)))

    def trial_started(self, trial_id: int, description: str) -> None:
        self.events.append(("trial_started", trial_id))

    def trial_finished(self, result: TrialResult, estimate: Estimate) -> None:
        self.events.append(("trial_finished", result.trial_id))

    def flush(self) -> None:
        self.events.append(("flush",))

    def closing_note(self, time_ns: int) -> LogMessage | None:
        return None if self.note is None else LogMessage(time_ns, LogLevel.INFO, self.note)

    def stop(self) -> None:
        self.events.append(("stop",))

    def kinds(self) -> list[str]:
        return [event[0] for event in self.events]

    def topics(self) -> Counter[str]:
        """The messages received per topic, the tick rows counted as the log holds them."""
        counts: Counter[str] = Counter()
        for event in self.events:
            if event[0] == "log":
                counts[event[1]] += 1
            elif event[0] == "ticks":
                counts[schemas.LOADCELL] += event[1]
                counts[schemas.SERVO_STATE] += event[2]
        return counts


def _run(out: Path, *sinks: RecordingSink, log_file: bool = True) -> RunReport:
    prepared = prepare_run(RunRequest(SMOKE, None, out, seed=0, run_id="sinks"))
    return execute_run(prepared, open_rig(prepared, devices=DeviceLevel.OBJECT), *sinks, log_file=log_file)


def _log_topics(path: Path) -> Counter[str]:
    with path.open("rb") as f:
        return Counter(channel.topic for _schema, channel, _message in make_reader(f).iter_messages())


def test_every_sink_gets_the_run_in_order_and_the_log_holds_what_they_got(tmp_path: Path) -> None:
    ticking = RecordingSink(wants_ticks=True, note="ticking sink closed")
    quiet = RecordingSink(wants_ticks=False)
    report = _run(tmp_path, ticking, quiet)
    assert report.exit_code == 0 and report.completed == report.planned
    kinds = ticking.kinds()
    assert kinds[0] == "start" and kinds[-1] == "stop"
    assert ticking.events[0] == ("start", "sinks", report.planned, 0)
    assert ("metadata", "sim_truth") in ticking.events  # at the end, before `stop`
    assert kinds.count("trial_started") == kinds.count("trial_finished") == report.completed
    assert kinds.count("flush") >= report.completed  # one after every trial at least
    # The MCAP file is one more sink: it holds exactly the messages a ticking sink was given.
    assert _log_topics(Path(report.log)) == ticking.topics()
    assert ticking.topics()[schemas.LOADCELL] > 0
    # Every sink hears the closing notes; one that wants no ticks gets everything else.
    assert ticking.events.count(("log", schemas.LOG)) == quiet.events.count(("log", schemas.LOG))
    assert "ticks" not in quiet.kinds()
    assert [e for e in ticking.events if e[0] != "ticks"] == quiet.events


def test_a_run_without_a_ticking_sink_builds_no_rows_and_measures_the_same(tmp_path: Path) -> None:
    """What `rig study` does: no log file, no sink wanting ticks; the per-tick rows and link scenes are
    not built, and the trials are those of the logged run with the same seed."""
    quiet = RecordingSink(wants_ticks=False)
    unlogged = _run(tmp_path / "unlogged", quiet, log_file=False)
    logged = _run(tmp_path / "logged")
    assert not Path(unlogged.log).exists()
    assert "ticks" not in quiet.kinds()
    topics = quiet.topics()
    assert topics[schemas.LINK_FRAMES] == topics[schemas.LINK_SCENE] == 0
    assert topics[schemas.TRIAL_RESULT] == unlogged.completed
    assert [t.to_json() for t in unlogged.trials] == [t.to_json() for t in logged.trials]


def test_rig_run_validates_the_protocol_and_out_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, run_cli: Any
) -> None:
    calls: Counter[str] = Counter()
    load_protocol, check_out_dir = run_module.load_protocol, run_module.check_out_dir

    def counted_load(*args: Any, **kwargs: Any) -> Any:
        calls["load_protocol"] += 1
        return load_protocol(*args, **kwargs)

    def counted_check(*args: Any, **kwargs: Any) -> None:
        calls["check_out_dir"] += 1
        check_out_dir(*args, **kwargs)

    monkeypatch.setattr(run_module, "load_protocol", counted_load)
    monkeypatch.setattr(run_module, "check_out_dir", counted_check)
    monkeypatch.setattr("rig.cli.run.check_out_dir", counted_check, raising=False)
    monkeypatch.setattr("rig.inputs.files.check_out_dir", counted_check)
    result = run_cli("run", SMOKE, "--out", tmp_path / "out", "--devices", "object", "--json")
    assert result.code == 0, result.err
    assert calls == {"load_protocol": 1, "check_out_dir": 1}


def test_a_bad_protocol_exits_2_in_one_line_before_out_is_made(tmp_path: Path, run_cli: Any) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(SMOKE.read_text() + "\nnot_a_field: 1\n")
    out = tmp_path / "new-out"
    result = run_cli("run", bad, "--out", out)
    assert result.code == 2 and result.out == ""
    assert len(result.err.strip().splitlines()) == 1 and str(bad) in result.err
    assert not out.exists()


def test_a_resumed_run_whose_journal_changed_after_validation_is_refused(tmp_path: Path) -> None:
    report = _run(tmp_path)
    journal_path = tmp_path / "sinks.journal.json"
    journal = json.loads(journal_path.read_text())
    journal["status"] = "interrupted"
    journal_path.write_text(json.dumps(journal))
    validated = validate_run(RunRequest(None, None, tmp_path, seed=0, resume="sinks"))
    assert validated.lock is None and validated.remaining == []
    journal["invocations"] += 1  # another invocation ran in between
    journal_path.write_text(json.dumps(journal))
    with pytest.raises(InputError, match="changed while this invocation started"):
        claim_run(validated)
    assert not (tmp_path / "sinks.lock").exists()  # given back
    assert report.exit_code == 0


def test_a_study_seed_runs_through_execute_run(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[int, bool]] = []
    real = worker.execute_run

    def counted(prepared: Any, rig: Any, *sinks: Any, log_file: bool = True) -> RunReport:
        calls.append((len(sinks), log_file))
        return real(prepared, rig, *sinks, log_file=log_file)

    monkeypatch.setattr(worker, "execute_run", counted)
    record = run_seed(StudySpec(str(SMOKE), None, DeviceLevel.OBJECT), 0)
    assert record.status == "completed" and record.trials_completed == record.trials_planned
    assert calls == [(0, False)]


class SampleKeepingSink(NullSink):
    """Keeps every load-cell sample it is offered, as it was offered."""

    wants_ticks = True

    def __init__(self) -> None:
        self.samples: list[LoadCellSample] = []

    def tick_rows(
        self, samples: list[LoadCellSample], states: Mapping[int, ServoState], roles: Mapping[int, ServoRole]
    ) -> None:
        self.samples += samples


def test_a_load_cell_sample_keeps_one_shape_from_the_driver_to_the_log(tmp_path: Path) -> None:
    """The sinks get the driver's `LoadCellSample`s (tare taken off), and the log holds exactly those."""
    kept = SampleKeepingSink()
    report = _run(tmp_path, kept)
    assert kept.samples and all(type(sample) is LoadCellSample for sample in kept.samples)
    with Path(report.log).open("rb") as f:
        logged = [
            (message.log_time, json.loads(message.data))
            for _schema, _channel, message in make_reader(f).iter_messages(topics=[schemas.LOADCELL])
        ]
    assert [(t, p.get("seq"), p["raw"], p["force_n"], p.get("device_time_us")) for t, p in logged] == [
        (s.time_ns, s.seq, s.raw, s.force_n, s.device_time_us) for s in kept.samples
    ]
