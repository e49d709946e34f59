"""RunLogger: queued writing, flushing, error reporting, crash survival (checked with mcap's own reader)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from rig.errors import RigError
from rig.log.format import schemas as S
from rig.log.format.examples import EXAMPLE_TIME_NS, example_payloads
from rig.log.format.log_format import METADATA_NAME as FORMAT_RECORD
from rig.log.format.log_format import format_metadata
from rig.log.reading.frames import frame_payloads
from rig.log.reading.reader import read_run
from rig.log.writing.writer import LIBRARY, LogWriteError, RunLogger
from rig.records import SlipMessage, TrialPhase, TrialState
from rig.sim.virtual_clock import VirtualClock

T0_NS = 1_767_225_600_000_000_000
MS = 1_000_000


def mcap_messages(path: Path) -> list[tuple[str, str, int, int, dict]]:
    """(topic, schema name, log time, publish time, payload) via the official Python reader."""
    with open(path, "rb") as f:
        return [
            (channel.topic, schema.name, m.log_time, m.publish_time, json.loads(m.data))
            for schema, channel, m in make_reader(f).iter_messages()
        ]


def test_round_trip_of_every_topic_with_metadata_and_attachments(tmp_path):
    clock = VirtualClock(epoch_ns=T0_NS)
    payloads = example_payloads()
    path = tmp_path / "run.mcap"
    with RunLogger(path, clock=clock, strict=True) as log:
        log.add_metadata("session", {"seed": "7", "clock": "virtual"})
        log.add_attachment("protocol.yaml", "application/yaml", b"trials: []\n", log_time_ns=T0_NS)
        for i, (topic, payload) in enumerate(payloads.items()):
            clock.advance_ns(3 * MS)
            log.log(topic, T0_NS + i * MS, payload)

    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().library == LIBRARY
        assert LIBRARY.startswith("rig-logger/") and " mcap-python/1.6" in LIBRARY
        summary = reader.get_summary()
        assert {s.name: s.encoding for s in summary.schemas.values()} == {
            spec.schema_name: "jsonschema" for spec in S.TOPICS.values()
        }
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        assert {m.name: m.metadata for m in reader.iter_metadata()} == {
            FORMAT_RECORD: format_metadata(),
            "session": {"seed": "7", "clock": "virtual"},
        }
        (attachment,) = reader.iter_attachments()
        assert (attachment.name, attachment.media_type, attachment.data) == (
            "protocol.yaml",
            "application/yaml",
            b"trials: []\n",
        )

    messages = mcap_messages(path)
    assert [m[0] for m in messages] == list(payloads)
    for i, (topic, schema_name, log_ns, publish_ns, payload) in enumerate(messages):
        assert schema_name == S.TOPICS[topic].schema_name
        assert log_ns == T0_NS + i * MS
        assert publish_ns == T0_NS + 3 * MS * (i + 1)  # the clock's time at enqueue
        assert payload == json.loads(json.dumps(payloads[topic]))

    run = read_run(path)
    assert run.complete and run.warnings == []
    assert run.message_counts == dict.fromkeys(payloads, 1)
    assert run.metadata == {FORMAT_RECORD: format_metadata(), "session": {"seed": "7", "clock": "virtual"}}
    slip = run.topic(S.SLIP).iloc[0]
    assert (slip["onset.sec"], slip["onset.nsec"]) == (1_767_225_600, 123_456_789)
    ((_, slip_payload),) = frame_payloads(run.topic(S.SLIP))
    assert SlipMessage.from_payload(slip_payload).event.onset_time_ns == EXAMPLE_TIME_NS  # exact
    assert slip["detector.drop_fraction"] == 0.2 and pd.isna(slip.get("detector.slope_n_per_s"))
    result = run.topic(S.TRIAL_RESULT).iloc[0]
    assert list(result["joint_angles_rad"]) == [0.0, 0.5]
    assert result["outcome"] == "slip" and result["slipped_joint"] == 2
    estimate = run.topic(S.ESTIMATE).iloc[0]
    assert estimate["k"] == 0.167 and list(estimate["k_ci"]) == [0.148, 0.185]
    assert estimate["joints"][0]["capacity_nm"] == 1.6
    log_row = run.topic(S.LOG).iloc[0]
    assert (log_row["level"], log_row["message"], log_row["line"]) == (3, "tension high", 12)


def test_strict_mode_rejects_nan_in_the_caller(tmp_path):
    with RunLogger(tmp_path / "a.mcap", strict=True) as log, pytest.raises(ValueError, match="force_n"):
        log.log(S.LOADCELL, T0_NS, {"seq": 1, "raw": 1, "force_n": float("nan"), "device_time_us": None})


def test_nan_without_strict_mode_is_reported_at_the_next_call_and_not_written(tmp_path):
    path = tmp_path / "a.mcap"
    log = RunLogger(path, strict=False)
    log.log(S.LOADCELL, T0_NS, S.loadcell_sample(raw=1, force_n=1.0))
    log.log(S.LOADCELL, T0_NS + MS, {"seq": None, "raw": 2, "force_n": float("nan"), "device_time_us": None})
    log.log(S.LOADCELL, T0_NS + 2 * MS, S.loadcell_sample(raw=3, force_n=3.0))
    with pytest.raises(
        LogWriteError, match=r"/rig/loadcell message at log time 1767225600001000000.*not written"
    ):
        log.flush()
    log.finish()  # the error was reported once; finishing works
    assert [m[4]["raw"] for m in mcap_messages(path)] == [1, 3]
    with open(path, "rb") as f:
        assert b"NaN" not in f.read()


def test_the_writer_process_has_its_own_process_group_so_a_terminal_ctrl_c_reaches_only_the_run(tmp_path):
    # A Ctrl-C in the writer's first instants, before it ignores SIGINT, would lose the log's end.
    log = RunLogger(tmp_path / "a.mcap")
    assert os.getpgid(log._process.pid) == log._process.pid != os.getpgid(0)
    log.finish()


def test_writer_process_failure_is_raised_in_the_caller_and_finish_does_not_hang(tmp_path):
    log = RunLogger(tmp_path / "a.mcap")
    log.log(S.LOADCELL, T0_NS, S.loadcell_sample(raw=1, force_n=1.0))
    log._process.kill()  # the writer process dies (e.g. killed by the OOM killer)
    log._process.wait(10)
    with pytest.raises(LogWriteError, match="writer process ended"):
        log.flush(timeout_s=10)
    with pytest.raises(LogWriteError, match="stopped writing"):
        log.log(S.LOADCELL, T0_NS + MS, S.loadcell_sample(raw=2, force_n=1.0))
    started = time.monotonic()
    with pytest.raises(LogWriteError):
        log.finish(timeout_s=10)
    assert time.monotonic() - started < 5
    assert issubclass(LogWriteError, RigError)


def test_finish_is_idempotent_and_logging_after_it_fails(tmp_path):
    log = RunLogger(tmp_path / "a.mcap")
    log.log(S.LOADCELL, T0_NS, S.loadcell_sample(raw=1, force_n=1.0))
    log.finish()
    log.finish()
    log.close()
    with pytest.raises(LogWriteError, match="after finish"):
        log.log(S.LOADCELL, T0_NS, S.loadcell_sample(raw=1, force_n=1.0))
    with pytest.raises(LogWriteError, match="after finish"):
        log.flush()
    assert read_run(tmp_path / "a.mcap").complete


def test_context_manager_finishes_the_file_when_the_body_raises(tmp_path):
    path = tmp_path / "a.mcap"
    with pytest.raises(RuntimeError, match="interlock"), RunLogger(path) as log:
        log.log(S.TRIAL_STATE, T0_NS, TrialState(1, TrialPhase.RAMP_SLOW).to_payload())
        raise RuntimeError("interlock")
    run = read_run(path)
    assert run.complete and run.message_counts == {S.TRIAL_STATE: 1}


def test_caller_errors_are_immediate_and_name_the_problem(tmp_path):
    with RunLogger(tmp_path / "a.mcap") as log:
        with pytest.raises(KeyError, match="unknown topic '/rig/nope'"):
            log.log("/rig/nope", T0_NS, {})
        with pytest.raises(TypeError):
            log.log(S.LOADCELL, float(T0_NS), S.loadcell_sample(raw=1, force_n=1.0))
        with pytest.raises(TypeError, match=r"keys and values must be strings.*'seed'"):
            log.add_metadata("session", {"seed": 7})
    with pytest.raises(FileExistsError):
        RunLogger(tmp_path / "a.mcap")
    with pytest.raises(ValueError, match="compression"):
        RunLogger(tmp_path / "b.mcap", compression="gzip")


def test_periodic_flush_puts_each_second_of_log_time_on_disk_before_finish(tmp_path):
    path = tmp_path / "live.mcap"
    log = RunLogger(path, flush_interval_s=1.0)
    try:
        for i in range(3500):  # 3.5 s of 1 kHz samples
            log.log(S.LOADCELL, T0_NS + i * MS, S.loadcell_sample(raw=i, force_n=0.0, seq=i))
        deadline = time.monotonic() + 20
        while True:
            run = read_run(path)
            count = run.message_counts.get(S.LOADCELL, 0)
            if count >= 3000 or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        assert count >= 3000
        assert not run.complete and "no footer (unfinished)" in run.warnings[0]
        assert list(run.topic(S.LOADCELL)["seq"][:3000]) == list(range(3000))
    finally:
        log.finish()
    assert read_run(path).message_counts == {S.LOADCELL: 3500}


def test_back_pressure_bounds_the_queue_and_loses_nothing(tmp_path):
    path = tmp_path / "a.mcap"
    with RunLogger(path, max_pending=50) as log:
        for i in range(3000):
            log.log(S.LOADCELL, T0_NS + i * MS, S.loadcell_sample(raw=i, force_n=0.5))
            assert log.pending <= 51 + 5  # a few may be queued between the check and the drain
    frame = read_run(path).topic(S.LOADCELL)
    assert list(frame["raw"]) == list(range(3000))


def _loadcell_columns(payloads: list[dict]) -> dict[str, list]:
    """`log_columns`' keyword columns for these `/rig/loadcell` payloads (a missing field as None)."""
    return {name: [p.get(name) for p in payloads] for name in S.ROW_FIELDS[S.LOADCELL]}


def test_log_columns_writes_what_log_would_in_order_with_one_publish_time_per_call(tmp_path):
    clock = VirtualClock()
    path = tmp_path / "a.mcap"
    with RunLogger(path, clock=clock, strict=True) as log:
        log.log(S.LOADCELL, T0_NS, S.loadcell_sample(raw=0, force_n=0.0, seq=0))
        for tick in range(3):
            clock.advance_ns(20 * MS)
            times = [T0_NS + (20 * tick + i) * MS for i in range(1, 21)]
            payloads = [S.loadcell_sample(raw=i, force_n=0.25 * i, seq=i) for i in range(1, 21)]
            log.log_columns(S.LOADCELL, times, **_loadcell_columns(payloads))
        log.log_columns(S.LOADCELL, [], **_loadcell_columns([]))
        assert log.messages_logged == 61
        with pytest.raises(TypeError, match="exactly the fields"):
            log.log_columns("/rig/nope", times, **_loadcell_columns(payloads))
        with pytest.raises(TypeError):
            log.log_columns(S.LOADCELL, [1.5], **_loadcell_columns(payloads[:1]))  # log times are integer ns
    messages = mcap_messages(path)
    assert len(messages) == 61
    assert [m[4] for m in messages[1:21]] == [
        S.loadcell_sample(raw=i, force_n=0.25 * i, seq=i) for i in range(1, 21)
    ]
    log_times = [m[2] for m in messages]
    assert log_times == sorted(log_times) and log_times[-1] == T0_NS + 60 * MS
    publish = [m[3] for m in messages[1:]]
    assert publish == [clock.time_ns() - (2 - tick) * 20 * MS for tick in range(3) for _ in range(20)]


def test_flush_with_fsync_and_the_messages_it_covers_are_on_disk(tmp_path):
    path = tmp_path / "a.mcap"
    log = RunLogger(path, flush_interval_s=3600)
    try:
        for i in range(10):
            log.log(S.LOADCELL, T0_NS + i * MS, S.loadcell_sample(raw=i, force_n=0.0))
        log.flush(fsync=True)
        assert read_run(path).message_counts == {S.LOADCELL: 10}
    finally:
        log.finish()


KILLED_WRITER = textwrap.dedent(
    """
    import os, signal, sys
    from rig.log.format import schemas as S
    from rig.records import TrialKind, TrialOutcome, TrialResult
    from rig.log.writing.writer import RunLogger

    path, blocks = sys.argv[1], int(sys.argv[2])
    log = RunLogger(path, flush_interval_s=3600)  # only the explicit flushes close chunks
    log.add_metadata("session", {"seed": "3"})
    seq = 0
    for _ in range(blocks):
        for _ in range(1000):
            log.log(S.LOADCELL, 1_767_225_600_000_000_000 + seq * 1_000_000,
                    S.loadcell_sample(raw=seq, force_n=seq * 1e-3, seq=seq))
            seq += 1
        log.log(S.TRIAL_RESULT, 1_767_225_600_000_000_000 + seq * 1_000_000, TrialResult(
            trial_id=seq // 1000, kind=TrialKind.JOINT_ESTIMATION, repeat=1, joint=1, distance_m=0.1,
            configuration_index=None, joint_angles_rad=None, start_time_ns=1_767_225_600_000_000_000,
            end_time_ns=1_767_225_600_000_000_000 + seq * 1_000_000, outcome=TrialOutcome.SLIP,
            peak_force_n=1.0, slip_mass_kg=0.1, predicted_force_n=None, predicted_mass_kg=None,
            percentage_error=None, slipped_joint=None, lever_arms_m=None, tare_n=0.0).to_payload())
        log.flush(wait=True)
    print(seq, flush=True)
    for _ in range(700):  # logged but never flushed
        log.log(S.LOADCELL, 1_767_225_600_000_000_000 + seq * 1_000_000,
                S.loadcell_sample(raw=seq, force_n=0.0, seq=seq))
        seq += 1
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


@pytest.mark.subprocess
def test_a_run_killed_with_sigkill_keeps_every_flushed_message(tmp_path):
    path = tmp_path / "killed.mcap"
    done = subprocess.run(
        [sys.executable, "-c", KILLED_WRITER, str(path), "5"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert done.returncode == -signal.SIGKILL, done.stderr
    flushed = int(done.stdout.strip())
    assert flushed == 5000

    # mcap 1.6.0's indexed reader gets nothing out of this file (no footer).
    with open(path, "rb") as f, pytest.raises(Exception):  # noqa: B017 - whatever the library raises
        list(make_reader(f).iter_messages())

    run = read_run(path)
    assert not run.complete
    assert len(run.warnings) == 1 and "no footer (unfinished)" in run.warnings[0]
    assert "recovered 5 complete chunks" in run.warnings[0]
    loadcell = run.topic(S.LOADCELL)
    assert list(loadcell["seq"][:flushed]) == list(range(flushed))
    assert list(run.topic(S.TRIAL_RESULT)["trial_id"]) == [1, 2, 3, 4, 5]
    assert run.metadata == {FORMAT_RECORD: format_metadata(), "session": {"seed": "3"}}
    assert run.reports[0].messages == len(loadcell) + 5
    assert os.path.getsize(path) > 0


def test_the_writer_process_encodes_load_cell_rows_exactly_as_the_json_encoder():
    from rig.log.format.encoding import row_encoder
    from rig.log.writing.writer_process import _DUMPS

    fields = S.ROW_FIELDS[S.LOADCELL]
    encode = row_encoder(fields, _DUMPS)
    floats = [0.0, -0.0, 5e-324, 1.7976931348623157e308, 0.1 + 0.2, -7.25, 1e16, 1e-7, 123456.789]
    for i, force in enumerate(floats):
        for seq, device_us in ((None, None), (i, None), (None, 2**40 + i), (2**33, 7)):
            payload = S.loadcell_sample(
                raw=(-1) ** i * 2**i, force_n=force, seq=seq, device_time_us=device_us
            )
            row = tuple(payload.get(field) for field in fields)
            assert S.row_payload(S.LOADCELL, row) == payload and None not in payload.values()
            assert encode(row) == _DUMPS(payload).encode()  # a missing value is left out
    # Other types go through the JSON encoder, as their payload would; it rejects NaN.
    for row in [(True, 1, 1.0, None), (1, 1, 1, None), (1, 1.0, 1.0, None), (10**400, 1, 1.0, 2)]:
        assert encode(row) == _DUMPS(S.row_payload(S.LOADCELL, row)).encode()
    with pytest.raises(ValueError):
        encode((1, 1, float("nan"), None))


def test_the_writer_process_starts_without_building_the_schemas():
    """The writer child takes the schemas from its parent: importing it must not import the schemas
    module, nor the records and the model the schemas are built from (a third of a second a run)."""
    code = (
        "import sys, rig.log.writing.writer_process; "
        "print(sorted(m for m in ('rig.log.format.schemas', 'model', 'numpy') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def test_log_columns_rows_write_the_same_json_as_log_and_a_bad_row_is_reported(tmp_path):
    path = tmp_path / "a.mcap"
    with RunLogger(path, strict=False) as log:  # strict would stop the NaN row in the caller
        payloads = [S.loadcell_sample(raw=i, force_n=i / 4, seq=i) for i in range(5)]
        log.log_columns(S.LOADCELL, [T0_NS + i * MS for i in range(5)], **_loadcell_columns(payloads))
        log.log(S.LOADCELL, T0_NS + 5 * MS, S.loadcell_sample(raw=5, force_n=1.25, seq=5))
        with pytest.raises(TypeError, match="log_columns"):
            log.log(S.LOADCELL, T0_NS, (7, 1, 1.0, None))  # type: ignore[arg-type]  # a tuple: whose order?
        log.log_columns(
            S.LOADCELL, [T0_NS + 6 * MS], seq=[6], raw=[6], force_n=[float("nan")], device_time_us=[None]
        )
        with pytest.raises(LogWriteError, match="not written: Out of range float"):
            log.flush()  # waits for the writer process, which reports the NaN row
        log.log(S.LOADCELL, T0_NS + 7 * MS, S.loadcell_sample(raw=7, force_n=1.75, seq=7))
    payloads = [m[4] for m in mcap_messages(path)]
    assert payloads[:6] == [S.loadcell_sample(raw=i, force_n=i / 4, seq=i) for i in range(6)]
    assert len(payloads) == 7 and payloads[-1]["raw"] == 7


def test_strict_mode_checks_each_named_field_of_a_row(tmp_path):
    """seq and raw swapped by a producer: the named column puts a None raw where the schema wants an int."""
    sample = S.loadcell_sample(raw=123456, force_n=1.5, seq=None)
    with RunLogger(tmp_path / "a.mcap", strict=True) as log:
        log.log_columns(S.LOADCELL, [T0_NS], **_loadcell_columns([sample]))
        with pytest.raises(ValueError, match="raw"):
            log.log_columns(
                S.LOADCELL,
                [T0_NS + MS],
                seq=[sample["raw"]],
                raw=[None],
                force_n=[1.5],
                device_time_us=[None],
            )
        with pytest.raises(ValueError, match="raw"):
            log.log_columns(
                S.LOADCELL, [T0_NS + MS], seq=[1], raw=["x"], force_n=[1.5], device_time_us=[None]
            )


def test_log_columns_checks_the_names(tmp_path):
    """The runner's path: one column per `ROW_FIELDS` name, in any order; the same messages as `log`."""
    samples = [S.loadcell_sample(raw=i - 2, force_n=i / 8, seq=i, device_time_us=1000 * i) for i in range(6)]
    times = [T0_NS + i * MS for i in range(6)]
    with RunLogger(tmp_path / "dicts.mcap", strict=True) as log:
        for t, payload in zip(times, samples, strict=True):
            log.log(S.LOADCELL, t, payload)
    with RunLogger(tmp_path / "columns.mcap", strict=True) as log:
        columns = _loadcell_columns(samples)
        log.log_columns(S.LOADCELL, iter(times), **{k: iter(v) for k, v in reversed(columns.items())})
        with pytest.raises(TypeError, match="exactly the fields"):
            log.log_columns(S.LOADCELL, times, seq=[1], raw=[2], force_n=[0.5])  # one missing
        with pytest.raises(TypeError, match="exactly the fields"):
            log.log_columns(S.SERVO_STATE, times, seq=[1])
    rows = [(m[2], m[4]) for m in mcap_messages(tmp_path / "dicts.mcap")]
    assert rows == [(m[2], m[4]) for m in mcap_messages(tmp_path / "columns.mcap")]
    assert [p for _, p in rows] == samples
    with RunLogger(tmp_path / "unequal.mcap") as log, pytest.raises(ValueError):  # columns of unequal length
        log.log_columns(S.LOADCELL, times[:2], seq=[1], raw=[2, 3], force_n=[0.5, 1], device_time_us=[1, 2])


_ROW_VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**60), max_value=2**60),
    st.sampled_from([S.MAX_SAFE_INT, S.MAX_SAFE_INT + 1, -S.MAX_SAFE_INT - 1]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=3),
)


@settings(max_examples=400, deadline=None)
@given(st.lists(_ROW_VALUES, min_size=3, max_size=5))
def test_strict_modes_fast_row_check_accepts_only_what_the_schema_accepts(row):
    """`row_passes` (the fast path) never accepts a row that `check_payload` (the plain check) refuses."""
    row = tuple(row)
    if S.row_passes(S.LOADCELL, row):
        S.check_payload(S.LOADCELL, S.row_payload(S.LOADCELL, row))


def test_strict_modes_fast_row_check_takes_the_rows_a_run_logs():
    assert S.row_passes(S.LOADCELL, (7, -120268, 0.00335, 2_000_000))
    assert S.row_passes(S.LOADCELL, (None, 5, -1.5, None))  # a format without seq or device clock
    assert not S.row_passes(S.LOADCELL, (1, 5, float("nan"), 2))  # the plain check says why
    assert not S.row_passes(S.LOADCELL, (1, None, 1.0, 2))  # raw is required
