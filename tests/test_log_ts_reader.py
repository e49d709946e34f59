"""Rig logs read in the official TypeScript reader (@mcap/core), run with node from tests/ts_reader.

Skipped unless `tests/ts_reader/node_modules` exists (`npm ci --prefix tests/ts_reader`; `.ci/run` does
it). `read.mjs` reports warnings for what a JavaScript reader such as Foxglove would get wrong (a
number beyond 2^53, a payload that is not an object, an unusable schema); rig logs must have none.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from mcap.writer import Writer

from rig.log.format import schemas as S
from rig.log.format.examples import example_payloads
from rig.log.format.log_format import METADATA_NAME as FORMAT_RECORD
from rig.log.reading.reader import read_run
from rig.log.writing.writer import RunLogger

TS_READER = Path(__file__).parent / "ts_reader"
T0_NS = 1_767_225_600_000_000_000
MS = 1_000_000

pytestmark = [
    pytest.mark.subprocess,
    pytest.mark.skipif(
        shutil.which("node") is None or not (TS_READER / "node_modules" / "@mcap" / "core").is_dir(),
        reason="needs node and `npm ci --prefix tests/ts_reader`",
    ),
]


def ts_read(path: Path, *args: str) -> dict:
    done = subprocess.run(
        ["node", str(TS_READER / "read.mjs"), str(path), *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=TS_READER,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.fixture(scope="module")
def rig_log(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("ts") / "run.mcap"
    with RunLogger(path, flush_interval_s=3600, strict=True) as log:
        log.add_metadata("session", {"seed": "1"})
        log.add_metadata("protocol", {"name": "demo"})
        log.add_attachment("protocol.yaml", "application/yaml", b"trials: []\n", log_time_ns=T0_NS)
        for topic, payload in example_payloads(T0_NS).items():
            log.log(topic, T0_NS, payload)
        for i in range(4000):
            log.log(S.LOADCELL, T0_NS + i * MS, S.loadcell_sample(raw=i, force_n=i * 1e-3, seq=i))
            if (i + 1) % 1000 == 0:
                log.flush()
    return path


def test_finished_rig_log_reads_in_the_indexed_typescript_reader(rig_log):
    found = ts_read(rig_log)
    assert found["reader"] == "McapIndexedReader" and found["library"].startswith("rig-logger/")
    ours = read_run(rig_log)
    assert {topic: entry["count"] for topic, entry in found["topics"].items()} == ours.message_counts
    assert {topic: entry["schema"] for topic, entry in found["topics"].items()} == {
        topic: S.TOPICS[topic].schema_name for topic in S.TOPICS
    }
    assert found["metadata"] == [FORMAT_RECORD, "session", "protocol"]
    assert found["attachments"] == ["protocol.yaml"]
    assert found["warnings"] == []


def test_crashed_copy_streams_its_complete_chunks_in_typescript(rig_log, tmp_path):
    data = rig_log.read_bytes()
    copy = tmp_path / "cut.mcap"
    copy.write_bytes(data[: int(len(data) * 0.7)])
    found = ts_read(copy, "--stream")
    assert found["complete"] is False
    ours = read_run(copy)
    assert {topic: entry["count"] for topic, entry in found["topics"].items()} == ours.message_counts
    assert 1000 <= ours.message_counts[S.LOADCELL] < 4000
    assert found["warnings"] == []


@pytest.mark.slow  # the default run (about 8 s, shared with other tests)
@pytest.mark.parametrize("mode", [(), ("--stream",)], ids=["indexed", "stream"])
def test_a_default_run_reads_in_typescript_without_a_warning(default_run_log, mode):
    found = ts_read(default_run_log, *mode)
    assert found["warnings"] == []
    assert found["complete"] is True
    ours = read_run(default_run_log)
    assert {topic: entry["count"] for topic, entry in found["topics"].items()} == ours.message_counts
    assert set(found["topics"]) == set(S.TOPICS)


def test_the_typescript_check_warns_of_integers_javascript_rounds(tmp_path):
    # Epoch-ns integers in a payload exceed 2^53 (what rig payloads avoid with {sec, nsec} times).
    path = tmp_path / "big.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="test")
        schema = writer.register_schema("big", "jsonschema", json.dumps({"type": "object"}).encode())
        channel = writer.register_channel("/big", "json", schema)
        for i in range(3):
            payload = json.dumps({"start_time_ns": T0_NS + i, "n": i}).encode()
            writer.add_message(channel, log_time=T0_NS, publish_time=T0_NS, data=payload)
        writer.finish()
    found = ts_read(path)
    warning = "/big: start_time_ns holds a number beyond 2^53 (not exact in JavaScript) (3 times)"
    assert found["warnings"] == [warning]
