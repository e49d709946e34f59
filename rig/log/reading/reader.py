"""The tolerant run reader: the MCAP files of one run (finished, crashed or damaged) as a `RunLog`.

Each file is scanned within bounds by `rig.log.reading.mcap_scan` (its docstring says how damage is
survived and what is bounded); `read_run` puts the scans of a run's files together, in log-time
order, and `RunLog` is the view of the run: per-topic DataFrames decoded on first use, metadata,
attachments, counts and the warnings of what was lost.

A run read with `topics=` keeps only those topics' messages, and with `deferred=` keeps none of
those topics' but still locates them; `RunLog.window` reads any topic's messages of a time span
from the files again (only the chunks that may hold them), and `RunLog.last_before` the latest
message before a time: so the high-rate topics (`/rig/loadcell`, `/rig/servo/state`) of a long run
are held one trial at a time, never whole. A topic that was not kept is read in full on the first
`RunLog.topic` call.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pandas as pd

from rig.errors import InputError
from rig.log.format.log_format import log_format_version
from rig.log.reading.frames import DEFAULT_BATCH_SIZE, TopicBatches, empty_frame, frame_payloads
from rig.log.reading.mcap_scan import (
    ALL_TIMES,
    Attachment,
    FileReport,
    FileScan,
    SpanSource,
    scan_file,
    scan_window,
)

Record = TypeVar("Record")


class RunLog:
    """The messages, metadata and attachments of one run, from one or more MCAP files."""

    def __init__(
        self,
        reports: list[FileReport],
        batches: dict[str, TopicBatches],
        counts: dict[str, int],
        schema_names: dict[str, str],
        metadata_by_file: dict[Path, dict[str, dict[str, str]]],
        attachments: list[Attachment],
        warnings: list[str],
        sources: list[SpanSource] | None = None,
        kept: frozenset[str] | None = None,
        deferred: frozenset[str] = frozenset(),
        batch_size: int = DEFAULT_BATCH_SIZE,
    ) -> None:
        self.reports = reports
        self.files = [r.path for r in reports]
        self.complete = bool(reports) and all(r.complete for r in reports)
        self.message_counts = counts
        self.schema_names = schema_names
        self.metadata_by_file = metadata_by_file
        self.attachments = attachments
        self.warnings = warnings
        self._batches = batches
        self._frames: dict[str, pd.DataFrame] = {}
        self._sources = sources or []  # in the order the files were scanned
        self._kept = kept  # the topics whose messages were kept (None: all but the deferred ones)
        self._deferred = deferred
        self._batch_size = batch_size

    @property
    def topics(self) -> list[str]:
        """Topics present in the files, sorted."""
        return sorted(self.message_counts)

    @property
    def metadata(self) -> dict[str, dict[str, str]]:
        """Metadata records by name; for a name in several files, the earliest file's record."""
        merged: dict[str, dict[str, str]] = {}
        for per_file in self.metadata_by_file.values():
            for name, values in per_file.items():
                merged.setdefault(name, values)
        return merged

    def topic(self, name: str) -> pd.DataFrame:
        """One topic's messages, indexed by UTC log time and sorted (stable) by it.

        Columns: `log_time_ns`, `publish_time_ns` and the payload fields (`{sec, nsec}` and other
        objects flattened to `a.b`). A rig topic without messages gives an empty frame with its
        declared columns; an unknown topic raises `KeyError`. The frame is cached: copy it before
        changing it.
        """
        if name not in self._frames:
            batches = self._batches.get(name)
            if batches is not None:
                self._frames[name] = batches.frame()
                self._note(batches.warnings)
                del self._batches[name]
            elif not self._was_kept(name) and self.message_counts.get(name):
                self._frames[name] = self.window(name, *ALL_TIMES)
            else:
                from rig.log.format import schemas

                if name not in schemas.TOPICS and name not in self.message_counts:
                    raise KeyError(
                        f"no topic {name!r} in this run; topics: {', '.join(self.topics) or 'none'}"
                    )
                self._frames[name] = empty_frame(name)
        return self._frames[name]

    def _was_kept(self, name: str) -> bool:
        return (self._kept is None or name in self._kept) and name not in self._deferred

    def _note(self, warnings: Iterable[str]) -> None:
        self.warnings.extend(w for w in warnings if w not in self.warnings)

    def window(self, name: str, first_ns: int, last_ns: int) -> pd.DataFrame:
        """One topic's messages logged from `first_ns` to `last_ns` (inclusive), as `topic` has them.

        The rows, their order and columns are those of `topic(name)` in that span. A kept topic is
        cut from its frame; any other is read again from the chunks that may hold the span, so the
        memory is that of the span's messages (and of the chunks holding them), not of the run.
        """
        if name in self._frames or (self._was_kept(name) and name in self._batches):
            frame = self.topic(name)
            times = frame["log_time_ns"].to_numpy()
            return frame[(times >= first_ns) & (times <= last_ns)]
        if name not in self.message_counts:
            return self.topic(name)  # empty, or KeyError for an unknown topic
        batches: dict[str, TopicBatches] = {}
        for source in self._sources:
            scan_window(source, batches, frozenset((name,)), first_ns, last_ns, self._batch_size)
        sink = batches.get(name)
        if sink is None:
            return empty_frame(name)
        frame = sink.frame()
        self._note(sink.warnings)
        return frame

    @property
    def format_versions(self) -> dict[Path, str]:
        """Each file's log format version (`rig.log.format.log_format`)."""
        return {path: log_format_version(path, meta) for path, meta in self.metadata_by_file.items()}

    def records(
        self, name: str, decode: Callable[[dict[str, Any]], Record]
    ) -> tuple[list[Record], int, str | None]:
        """One topic's messages decoded into typed records by `decode` (e.g. `TrialResult.from_payload`).

        Returns the records in log order, the count of payloads that did not decode (KeyError,
        TypeError, ValueError: damaged, or not of this log format) and the first such problem.
        """
        records: list[Record] = []
        failed = 0
        first: str | None = None
        for _, payload in frame_payloads(self.topic(name)):
            try:
                records.append(decode(payload))
            except (KeyError, TypeError, ValueError) as exc:
                failed += 1
                if first is None:
                    first = f"no {exc}" if isinstance(exc, KeyError) else str(exc)
        return records, failed, first

    def read_all(self, name: str) -> pd.DataFrame:
        """One topic's messages as `topic` has them, without keeping them.

        A deferred topic is read from the files again, chunk by chunk, on every call.
        """
        return self.window(name, *ALL_TIMES)

    def last_before(
        self, name: str, time_ns: int, keep: Callable[[pd.DataFrame], pd.DataFrame] = lambda f: f
    ) -> pd.Series | None:
        """The latest message of a topic logged before `time_ns` among the rows `keep` keeps, or None.

        The row `topic(name)` restricted by `keep` has last among those before `time_ns` (latest log
        time; of equal times, the last in the files). Read back from the latest chunks first, one
        chunk at a time, until no earlier chunk can hold a later message.
        """
        if name in self._frames or (self._was_kept(name) and name in self._batches):
            frame = keep(self.window(name, 0, time_ns - 1))
            return None if frame.empty else frame.iloc[-1]
        candidates = [
            (span.last_log_time_ns, index, span.offset, span)
            for index, source in enumerate(self._sources)
            for span in source.spans
            if span.first_log_time_ns < time_ns
        ]
        candidates.sort(key=lambda c: c[0], reverse=True)
        best: tuple[int, int, int] | None = None  # log time, file index, span offset
        best_row = None
        for span_last, index, offset, span in candidates:
            if best is not None and span_last < best[0]:
                break
            batches: dict[str, TopicBatches] = {}
            source = self._sources[index]
            scan_window(source, batches, frozenset((name,)), 0, time_ns - 1, self._batch_size, spans=(span,))
            sink = batches.get(name)
            if sink is None:
                continue
            frame = keep(sink.frame())
            if frame.empty:
                continue
            row = frame.iloc[-1]
            key = (int(np.int64(row["log_time_ns"])), index, offset)
            if best is None or key > best:
                best, best_row = key, row
        return best_row


def mcap_files(paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]]) -> list[Path]:
    """The MCAP files named by a path, a directory (its `*.mcap`) or a list of either."""
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    files: list[Path] = []
    for item in paths:
        path = Path(item)
        if path.is_dir():
            found = sorted(path.glob("*.mcap"))
            if not found:
                raise InputError(f"{path}: no .mcap files in this directory")
            files.extend(found)
        elif path.is_file():
            files.append(path)
        else:
            raise InputError(f"{path}: no such file or directory")
    if not files:
        raise InputError("no MCAP files given")
    return list(dict.fromkeys(files))


def read_run(
    paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]],
    *,
    topics: Iterable[str] | None = None,
    deferred: Iterable[str] = (),
    batch_size: int = DEFAULT_BATCH_SIZE,
) -> RunLog:
    """Read one run from MCAP files (a path, a directory or a list), tolerating crashes and damage.

    :param topics: decode only these topics (all are still counted); None decodes every topic.
    :param deferred: topics not decoded now but read by time span later (`RunLog.window`); their
        channels are checked (a non-JSON one is warned about) as for a decoded topic.
    :param batch_size: payloads decoded per batch; bounds the memory of pending raw payloads.
    """
    wanted = None if topics is None else frozenset(topics)
    later = frozenset(deferred)
    batches: dict[str, TopicBatches] = {}
    scans: list[FileScan] = []
    sources: list[SpanSource] = []
    for path in mcap_files(paths):
        scan = FileScan(
            path=path,
            size=path.stat().st_size,
            batches=batches,
            wanted=wanted,
            batch_size=batch_size,
            deferred=later,
        )
        if scan.size == 0:
            scan.warn("empty file (nothing was written); no data")
        else:
            scan_file(scan)
        if scan.counts.get(0):
            scan.warn(f"{scan.counts[0]} messages on channels whose Channel record was lost; skipped")
        log_format_version(path, scan.metadata)  # refuses a format this rig cannot read
        scans.append(scan)
        sources.append(scan.source())
    for sink in batches.values():
        sink.decode_pending()

    scans.sort(key=lambda s: (s.first_log_time_ns is None, s.first_log_time_ns or 0, str(s.path)))
    counts: dict[str, int] = {}
    schema_names: dict[str, str] = {}
    for scan in scans:
        for channel_id, channel in scan.channels.items():
            counts[channel.topic] = counts.get(channel.topic, 0) + scan.counts.get(channel_id, 0)
            schema_names.setdefault(channel.topic, channel.schema_name)
    warnings = [w for scan in scans for w in scan.warnings]
    warnings += [w for sink in batches.values() for w in sink.warnings]
    return RunLog(
        reports=[scan.report() for scan in scans],
        batches=batches,
        counts=counts,
        schema_names=schema_names,
        metadata_by_file={scan.path: scan.metadata for scan in scans},
        attachments=[a for scan in scans for a in scan.attachments],
        warnings=warnings,
        sources=sources,
        kept=wanted,
        deferred=later,
        batch_size=batch_size,
    )
