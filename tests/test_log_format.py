"""The log format's version: written into every log, read back, an unknown major version refused."""

from __future__ import annotations

import pytest
from mcap.writer import Writer

import rig
from rig.errors import InputError
from rig.log.format.log_format import LOG_FORMAT_VERSION, METADATA_NAME, UNVERSIONED, format_metadata
from rig.log.reading.reader import read_run
from rig.log.writing.writer import RunLogger
from rig.sim.virtual_clock import VirtualClock

T0_NS = 1_767_225_600_000_000_000


def _bare_log(path, metadata):
    """An MCAP file with these metadata records and no messages, written by mcap's own writer."""
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="test")
        for name, data in metadata.items():
            writer.add_metadata(name, data)
        writer.finish()
    return path


def test_every_log_states_its_format_version_and_the_release_that_wrote_it(tmp_path):
    path = tmp_path / "run.mcap"
    with RunLogger(path, clock=VirtualClock(epoch_ns=T0_NS)):
        pass
    run = read_run(path)
    assert run.metadata[METADATA_NAME] == {"version": LOG_FORMAT_VERSION, "writer": f"rig {rig.__version__}"}
    assert run.format_versions == {path: LOG_FORMAT_VERSION}


def test_a_log_from_before_the_version_record_reads_as_1_0(tmp_path):
    path = _bare_log(tmp_path / "old.mcap", {"session": {"seed": "1"}})
    assert read_run(path).format_versions == {path: UNVERSIONED} == {path: "1.0"}


def test_a_newer_minor_version_is_read(tmp_path):
    path = _bare_log(tmp_path / "minor.mcap", {METADATA_NAME: {"version": "1.7", "writer": "rig 0.3.0"}})
    assert read_run(path).format_versions == {path: "1.7"}


@pytest.mark.parametrize("version", ["2.0", "0.9", "x"])
def test_an_unknown_major_version_is_refused_naming_version_and_release(tmp_path, version):
    path = _bare_log(tmp_path / "new.mcap", {METADATA_NAME: {"version": version, "writer": "rig 9.1.0"}})
    with pytest.raises(InputError) as caught:
        read_run(path)
    message = str(caught.value)
    assert "\n" not in message
    assert f"log format {version} (written by rig 9.1.0)" in message and str(path) in message
    assert "allowed: format 1.x" in message


def test_rig_replay_exits_2_with_one_line_on_an_unknown_major_version(tmp_path, run_cli):
    path = _bare_log(tmp_path / "new.mcap", {METADATA_NAME: {**format_metadata(), "version": "2.0"}})
    result = run_cli("replay", str(path))
    assert result.code == 2
    assert "log format 2.0" in result.err and "Traceback" not in result.err
