"""The log format's version: written into every log as MCAP metadata, checked by the reader.

`LOG_FORMAT_VERSION` is "major.minor". A minor step only adds (a field, a topic, a metadata key) and
old readers ignore what they do not know; a major step changes or removes something and a reader
refuses a major version it does not know, with one line naming the version and the rig release that
wrote it. The history of the versions is in docs/formats.md ("Log format versions").

A log without the record is read as version 1.0: it was written by rig 0.1.0 before the record was
added, in the format that became 1.0.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import rig
from rig.errors import InputError

LOG_FORMAT_VERSION = "1.0"
METADATA_NAME = "rig.log_format"  # the MCAP metadata record: {"version": ..., "writer": "rig X.Y.Z"}
UNVERSIONED = "1.0"  # the version of a log written before the record existed


def format_metadata() -> dict[str, str]:
    """The metadata record every log starts with."""
    return {"version": LOG_FORMAT_VERSION, "writer": f"rig {rig.__version__}"}


def _major(version: str) -> int | None:
    head, _, _ = version.partition(".")
    return int(head) if head.isdigit() else None


def log_format_version(path: Path, metadata: Mapping[str, Mapping[str, str]]) -> str:
    """A file's format version from its metadata; InputError for a major version this rig does not read."""
    record = metadata.get(METADATA_NAME)
    if record is None:
        return UNVERSIONED
    version = str(record.get("version", ""))
    if _major(version) != _major(LOG_FORMAT_VERSION):
        writer = record.get("writer") or "an unknown rig release"
        raise InputError(
            f"{path}: log format {version or '(none)'} (written by {writer}); allowed: format "
            f"{_major(LOG_FORMAT_VERSION)}.x (this is rig {rig.__version__}): read it with the release "
            "that wrote it or a newer one"
        )
    return version
