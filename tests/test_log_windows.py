"""Reading a time window of a topic again (`RunLog.window`, `RunLog.last_before`): the same rows as the
whole topic has in that window, from finished, unfinished, unchunked, out-of-order and multi-file logs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.writer import CompressionType, Writer

from rig.log.format import schemas as S
from rig.log.reading.reader import RunLog, read_run
from rig.log.writing.writer import RunLogger

T0_NS = 1_767_225_600_000_000_000
MS = 1_000_000


def _servo(i: int, role: str) -> dict:
    return S.servo_state(
        servo_id=1 if role == "winch" else 2,
        role=role,
        position_rad=i * 1e-3,
        velocity_rad_s=float(i % 5) - 2.0,
        current_a=0.1,
        hardware_error=0,
        moving=True,
    )


def write_log(path: Path, n: int, *, back_every: int = 0, start: int = 0, chunk_size: int = 4096) -> Path:
    """n load-cell samples 1 ms apart, a servo state (winch or joint) every 7th; small chunks.

    `back_every`: every that many samples the log time goes back 40 ms (late samples across chunks).
    """
    with RunLogger(path, chunk_size=chunk_size, flush_interval_s=3600) as log:
        for i in range(start, start + n):
            t = T0_NS + i * MS - (40 * MS if back_every and i % back_every == 0 else 0)
            log.log(S.LOADCELL, t, S.loadcell_sample(raw=i, force_n=i * 1e-3, seq=i % 65536))
            if i % 7 == 0:
                log.log(S.SERVO_STATE, t, _servo(i, "winch" if i % 21 else "joint"))
    return path


def write_unchunked(path: Path, n: int) -> Path:
    """The same kind of log written by mcap's Writer without chunks (every message a top-level record)."""
    with open(path, "wb") as f:
        writer = Writer(f, use_chunking=False, compression=CompressionType.NONE)
        writer.start("rig", "test")
        schema = writer.register_schema("rig.LoadCellSample", "jsonschema", b"{}")
        channel = writer.register_channel(S.LOADCELL, "json", schema)
        for i in range(n):
            data = f'{{"raw": {i}, "force_n": {i * 1e-3}, "seq": {i}}}'.encode()
            writer.add_message(channel, T0_NS + i * MS, data, T0_NS + i * MS)
        writer.finish()
    return path


def _windows(frame: pd.DataFrame, count: int, seed: int) -> list[tuple[int, int]]:
    times = frame["log_time_ns"].to_numpy()
    rng = np.random.default_rng(seed)
    spans = [(int(times.min()) - 5 * MS, int(times.max()) + 5 * MS), (int(times[3]), int(times[3]))]
    for _ in range(count):
        a, b = sorted(int(v) for v in rng.integers(int(times.min()) - 50 * MS, int(times.max()) + 50 * MS, 2))
        spans.append((a, b))
    return spans


def _check_windows(deferred: RunLog, whole: RunLog, topic: str, seed: int = 0) -> None:
    frame = whole.topic(topic)
    times = frame["log_time_ns"].to_numpy()
    for first, last in _windows(frame, 25, seed):
        expected = frame[(times >= first) & (times <= last)]
        pd.testing.assert_frame_equal(deferred.window(topic, first, last), expected)


def _winch(frame: pd.DataFrame) -> pd.DataFrame:
    return frame[frame["role"] == "winch"]


def _check_last_before(deferred: RunLog, whole: RunLog, seed: int = 0) -> None:
    frame = whole.topic(S.SERVO_STATE)
    times = frame["log_time_ns"].to_numpy()
    rng = np.random.default_rng(seed)
    queries = [int(times.min()), int(times.min()) + 1, int(times.max()) + 1]
    queries += [int(v) for v in rng.integers(int(times.min()), int(times.max()), 25)]
    for time_ns in queries:
        before = _winch(frame[times < time_ns])
        found = deferred.last_before(S.SERVO_STATE, time_ns, _winch)
        if before.empty:
            assert found is None
        else:
            pd.testing.assert_series_equal(found, before.iloc[-1])


@pytest.mark.parametrize("back_every", [0, 50])
def test_a_window_has_the_rows_the_whole_topic_has_in_it(tmp_path, back_every):
    path = write_log(tmp_path / "run.mcap", 3000, back_every=back_every)
    whole = read_run(path)
    deferred = read_run(path, deferred=[S.LOADCELL, S.SERVO_STATE])
    assert deferred.complete and deferred.warnings == whole.warnings == []
    assert deferred.message_counts == whole.message_counts
    assert len(deferred._sources[0].spans) > 20  # small chunks: a window reads a few of them
    for topic in (S.LOADCELL, S.SERVO_STATE):
        _check_windows(deferred, whole, topic)
    _check_last_before(deferred, whole)
    # Asked for whole, a deferred topic is read in full, the same as when kept.
    pd.testing.assert_frame_equal(deferred.topic(S.LOADCELL), whole.topic(S.LOADCELL))


def test_a_window_of_an_unfinished_log_reads_its_complete_chunks(tmp_path):
    path = write_log(tmp_path / "run.mcap", 3000)
    cut = tmp_path / "cut.mcap"
    data = path.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    whole = read_run(cut)
    deferred = read_run(cut, deferred=[S.LOADCELL, S.SERVO_STATE])
    assert not deferred.complete and deferred.warnings == whole.warnings
    assert 0 < len(whole.topic(S.LOADCELL)) < 3000
    _check_windows(deferred, whole, S.LOADCELL, seed=1)
    _check_last_before(deferred, whole, seed=1)


def test_a_window_of_a_log_without_chunks(tmp_path):
    path = write_unchunked(tmp_path / "flat.mcap", 40_000)
    whole = read_run(path)
    deferred = read_run(path, deferred=[S.LOADCELL])
    assert len(whole.topic(S.LOADCELL)) == 40_000
    spans = deferred._sources[0].spans
    assert len(spans) > 1 and not any(s.chunk for s in spans)  # runs of records, each bounded
    _check_windows(deferred, whole, S.LOADCELL, seed=2)


def test_a_window_of_a_run_in_several_files(tmp_path):
    # The second file restarts at the first's times (as a resumed simulated run does): a window
    # has both files' messages in the order the whole topic has them.
    first = write_log(tmp_path / "a.mcap", 1500)
    second = write_log(tmp_path / "b.mcap", 1500, start=700)
    whole = read_run([first, second])
    deferred = read_run([first, second], deferred=[S.LOADCELL, S.SERVO_STATE])
    for topic in (S.LOADCELL, S.SERVO_STATE):
        _check_windows(deferred, whole, topic, seed=3)
    _check_last_before(deferred, whole, seed=3)


def test_a_kept_topic_is_cut_from_its_frame(tmp_path):
    path = write_log(tmp_path / "run.mcap", 1000)
    kept = read_run(path)
    _check_windows(kept, read_run(path), S.LOADCELL, seed=4)
    _check_last_before(kept, read_run(path), seed=4)
    assert read_run(path, deferred=[S.LOADCELL]).window(S.SLIP, 0, 2**63).empty  # declared, no messages
    with pytest.raises(KeyError):
        kept.window("/not/a/topic", 0, 2**63)
