"""read_run: finished, truncated, corrupted and multi-file logs into per-topic DataFrames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from rig.errors import InputError
from rig.log.format import schemas as S
from rig.log.format.log_format import METADATA_NAME as FORMAT_RECORD
from rig.log.format.log_format import format_metadata
from rig.log.reading.reader import read_run
from rig.log.writing.writer import RunLogger

T0_NS = 1_767_225_600_000_000_000
MS = 1_000_000


def write_loadcell_log(path: Path, n: int, *, per_chunk: int = 500, start: int = 0, **kwargs) -> Path:
    """n load-cell samples at 1 kHz (seq = index), a flush every `per_chunk`; plus a servo state every 10."""
    with RunLogger(path, flush_interval_s=3600, **kwargs) as log:
        log.add_metadata("session", {"part": str(start)})
        log.add_attachment("rig.yaml", "application/yaml", b"servos: []\n", log_time_ns=T0_NS)
        for i in range(start, start + n):
            t = T0_NS + i * MS
            log.log(S.LOADCELL, t, S.loadcell_sample(raw=i, force_n=i * 0.001, seq=i if i % 7 else None))
            if i % 10 == 0:
                state = S.servo_state(
                    servo_id=1,
                    role="winch",
                    position_rad=i * 1e-3,
                    velocity_rad_s=0.0,
                    current_a=0.1,
                    hardware_error=0,
                    moving=True,
                )
                log.log(S.SERVO_STATE, t, state)
            if (i + 1 - start) % per_chunk == 0:
                log.flush()
    return path


def chunk_spans(path: Path) -> list[tuple[int, int, int, int]]:
    """(start offset, end offset, first log time, last log time) of each chunk, from the summary."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return [
        (
            c.chunk_start_offset,
            c.chunk_start_offset + c.chunk_length,
            c.message_start_time,
            c.message_end_time,
        )
        for c in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    ]


def seqs_between(first_ns: int, last_ns: int) -> list[int]:
    return list(range((first_ns - T0_NS) // MS, (last_ns - T0_NS) // MS + 1))


@pytest.fixture(scope="module")
def finished_log(tmp_path_factory) -> Path:
    return write_loadcell_log(tmp_path_factory.mktemp("logs") / "run.mcap", 3000)


def test_finished_log_reads_completely_through_the_index(finished_log):
    run = read_run(finished_log)
    assert run.complete and run.warnings == []
    assert run.files == [finished_log] and run.reports[0].finished and run.reports[0].chunks == 6
    assert run.message_counts == {S.LOADCELL: 3000, S.SERVO_STATE: 300}
    assert run.schema_names == {S.LOADCELL: "rig.LoadCellSample", S.SERVO_STATE: "rig.ServoState"}
    frame = run.topic(S.LOADCELL)
    assert list(frame["raw"]) == list(range(3000))
    assert frame["force_n"].to_numpy() == pytest.approx(np.arange(3000) * 0.001, abs=0)
    assert frame["log_time_ns"].dtype == np.int64 and frame["seq"].dtype == "Int64"
    assert frame["seq"].isna().sum() == len(range(0, 3000, 7))
    assert frame.index[5] == pd.Timestamp(T0_NS + 5 * MS, unit="ns", tz="UTC")
    assert (frame["publish_time_ns"] > 0).all()
    assert run.metadata == {FORMAT_RECORD: format_metadata(), "session": {"part": "0"}}
    (attachment,) = run.attachments
    assert (attachment.name, attachment.data, attachment.file) == ("rig.yaml", b"servos: []\n", finished_log)


def test_python_mcap_reader_agrees(finished_log):
    with open(finished_log, "rb") as f:
        official = [
            json.loads(m.data)["raw"] for _, _, m in make_reader(f).iter_messages(topics=[S.LOADCELL])
        ]
    assert official == list(read_run(finished_log).topic(S.LOADCELL)["raw"])


def test_copy_cut_at_70_percent_keeps_every_complete_chunk(finished_log, tmp_path):
    data = finished_log.read_bytes()
    cut = int(len(data) * 0.7)
    copy = tmp_path / "cut.mcap"
    copy.write_bytes(data[:cut])
    complete = [span for span in chunk_spans(finished_log) if span[1] <= cut]
    assert 2 <= len(complete) < 6

    run = read_run(copy)
    assert not run.complete and not run.reports[0].finished
    (warning,) = run.warnings
    assert warning.startswith("cut.mcap: no footer (unfinished); recovered ")
    assert f"recovered {len(complete)} complete chunks" in warning and "lost the tail after byte" in warning
    expected = seqs_between(complete[0][2], complete[-1][3])
    assert list(run.topic(S.LOADCELL)["raw"]) == expected
    assert run.metadata == {FORMAT_RECORD: format_metadata(), "session": {"part": "0"}}


def flip_bytes(path: Path, offset: int, count: int = 16) -> None:
    data = bytearray(path.read_bytes())
    for i in range(offset, offset + count):
        data[i] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("finished", [True, False], ids=["finished", "unfinished"])
def test_corrupted_chunk_is_skipped_and_the_others_come_back(finished_log, tmp_path, finished):
    copy = tmp_path / "bad.mcap"
    data = finished_log.read_bytes()
    spans = chunk_spans(finished_log)
    if not finished:
        data = data[: spans[-1][1]]  # drop the summary and footer: the linear path
    copy.write_bytes(data)
    second = spans[1]
    flip_bytes(copy, (second[0] + second[1]) // 2)

    run = read_run(copy)
    assert not run.complete
    # zstd either fails or, without a frame checksum, decodes garbage that the chunk CRC catches
    (warning,) = [w for w in run.warnings if f"chunk at byte {second[0]}:" in w]
    assert warning.endswith("; skipped") and ("decompression failed" in warning or "CRC mismatch" in warning)
    lost = set(seqs_between(second[2], second[3]))
    assert list(run.topic(S.LOADCELL)["raw"]) == [i for i in range(3000) if i not in lost]
    assert run.reports[0].chunks_skipped == 1 and run.reports[0].chunks == 5


def test_crc_catches_corruption_in_an_uncompressed_chunk(tmp_path):
    path = write_loadcell_log(tmp_path / "raw.mcap", 1500, compression="none")
    second = chunk_spans(path)[1]
    flip_bytes(path, (second[0] + second[1]) // 2, count=4)
    run = read_run(path)
    assert any("CRC mismatch" in w for w in run.warnings)
    lost = set(seqs_between(second[2], second[3]))
    assert list(run.topic(S.LOADCELL)["raw"]) == [i for i in range(1500) if i not in lost]


def test_damaged_record_header_resynchronizes_on_the_next_chunk(finished_log, tmp_path):
    spans = chunk_spans(finished_log)
    data = bytearray(finished_log.read_bytes()[: spans[-1][1]])  # unfinished
    second = spans[1]
    data[second[0] + 1 : second[0] + 9] = (2**62).to_bytes(8, "little")  # the chunk's length field
    copy = tmp_path / "garbled.mcap"
    copy.write_bytes(bytes(data))

    run = read_run(copy)
    assert any(f"byte {second[0]}: invalid record header" in w and "skipped" in w for w in run.warnings)
    assert any("recovered 5 complete chunks" in w for w in run.warnings)
    lost = set(seqs_between(second[2], second[3]))
    assert list(run.topic(S.LOADCELL)["raw"]) == [i for i in range(3000) if i not in lost]


@pytest.mark.slow
def test_several_files_combine_into_one_run_sorted_by_time(tmp_path):
    later = write_loadcell_log(tmp_path / "run.part2.mcap", 1000, start=1000)
    earlier = write_loadcell_log(tmp_path / "run.mcap", 1000)
    cut = tmp_path / "run.part3.mcap"
    write_loadcell_log(cut, 1000, start=2000)
    cut.write_bytes(cut.read_bytes()[: chunk_spans(cut)[0][1]])  # a crashed third part: only chunk 1

    run = read_run(tmp_path)
    assert run.files == [earlier, later, cut]
    assert not run.complete and [r.complete for r in run.reports] == [True, True, False]
    assert len(run.warnings) == 1 and run.warnings[0].startswith("run.part3.mcap: no footer")
    frame = run.topic(S.LOADCELL)
    assert list(frame["raw"]) == list(range(2500))
    assert frame.index.is_monotonic_increasing
    assert run.message_counts[S.LOADCELL] == 2500
    assert run.metadata == {FORMAT_RECORD: format_metadata(), "session": {"part": "0"}}
    assert [m["session"]["part"] for m in run.metadata_by_file.values()] == ["0", "1000", "2000"]
    assert len(run.attachments) == 3
    assert list(read_run([later, earlier]).topic(S.SERVO_STATE)["position_rad"]) == pytest.approx(
        [i * 1e-3 for i in range(0, 2000, 10)]
    )


def test_topic_filter_counts_everything_and_reads_the_rest_on_demand(finished_log):
    run = read_run(finished_log, topics=[S.SERVO_STATE])
    assert run.message_counts == {S.LOADCELL: 3000, S.SERVO_STATE: 300}
    assert len(run.topic(S.SERVO_STATE)) == 300
    # A topic not kept is read from the file when first asked for, the same as when kept.
    pd.testing.assert_frame_equal(run.topic(S.LOADCELL), read_run(finished_log).topic(S.LOADCELL))


def test_missing_topics_and_bad_paths(finished_log, tmp_path):
    run = read_run(finished_log)
    slip = run.topic(S.SLIP)
    assert slip.empty and {"log_time_ns", "onset.sec", "peak_force_n", "joint"} <= set(slip.columns)
    with pytest.raises(KeyError, match="no topic '/elsewhere'"):
        run.topic("/elsewhere")
    with pytest.raises(InputError, match="no such file"):
        read_run(tmp_path / "nope.mcap")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(InputError, match=r"no \.mcap files"):
        read_run(tmp_path / "empty_dir")
    (tmp_path / "notes.mcap").write_text("hello, this is not a log")
    with pytest.raises(InputError, match=r"notes\.mcap: not an MCAP file"):
        read_run(tmp_path / "notes.mcap")
    (tmp_path / "zero.mcap").write_bytes(b"")
    zero = read_run(tmp_path / "zero.mcap")
    assert zero.message_counts == {} and "empty file" in zero.warnings[0] and not zero.complete


def test_payloads_that_are_not_strict_json_are_dropped_with_a_warning(tmp_path):
    """A file from another writer: a NaN payload and a truncated one among valid rows."""
    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start()
        spec = S.TOPICS[S.LOADCELL]
        schema_id = writer.register_schema(spec.schema_name, "jsonschema", spec.schema_bytes)
        channel_id = writer.register_channel(S.LOADCELL, "json", schema_id)
        rows = [b'{"seq":1,"raw":1,"force_n":1.0,"device_time_us":null}', b'{"seq":2,"raw":2,"force_n":NaN}']
        rows += [b'{"seq":3,"raw":3', b'{"seq":4,"raw":4,"force_n":4.5,"device_time_us":9}']
        for i, data in enumerate(rows):
            writer.add_message(channel_id, T0_NS + i * MS, data, T0_NS + i * MS)
        writer.finish()
    run = read_run(path)
    frame = run.topic(S.LOADCELL)
    assert list(frame["seq"]) == [1, 2, 4]  # Python's json accepts NaN, so row 2 is kept with NaN
    assert np.isnan(frame["force_n"].iloc[1])
    assert any("decoded row by row; 1 messages were not JSON objects" in w for w in run.warnings)


def test_small_batches_out_of_order_times_and_fields_added_mid_run(tmp_path):
    path = tmp_path / "a.mcap"
    with RunLogger(path) as log:
        for i in range(250):
            # log times go back by 5 ms every 50 messages (e.g. a late servo read)
            log.log(
                S.LOADCELL,
                T0_NS + i * MS - (5 * MS if i % 50 == 0 else 0),
                S.loadcell_sample(raw=i, force_n=1),
            )
    run = read_run(path, batch_size=40)
    frame = run.topic(S.LOADCELL)
    assert frame.index.is_monotonic_increasing
    assert sorted(frame["raw"]) == list(range(250)) and len(frame) == 250
    assert frame["device_time_us"].isna().all() and frame["device_time_us"].dtype == "Int64"


@pytest.mark.slow
@settings(max_examples=15, deadline=None)
@given(
    rows=st.lists(
        st.tuples(
            st.integers(-(2**40), 2**40),
            st.floats(allow_nan=False, allow_infinity=False, width=64),
            st.one_of(st.none(), st.integers(0, 2**32)),
        ),
        min_size=1,
        max_size=60,
    )
)
def test_loadcell_values_round_trip_exactly(tmp_path_factory, rows):
    path = tmp_path_factory.mktemp("prop") / "a.mcap"
    with RunLogger(path, chunk_size=256) as log:
        for i, (raw, force_n, seq) in enumerate(rows):
            log.log(S.LOADCELL, T0_NS + i, S.loadcell_sample(raw=raw, force_n=force_n, seq=seq))
    frame = read_run(path, batch_size=7).topic(S.LOADCELL)
    assert list(frame["raw"]) == [r[0] for r in rows]
    assert frame["force_n"].tolist() == [r[1] for r in rows]
    assert [None if pd.isna(s) else int(s) for s in frame["seq"]] == [r[2] for r in rows]
