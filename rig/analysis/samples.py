"""One trial's logged load-cell samples, read from the log for that trial alone.

Replay never holds a run's `/rig/loadcell` samples whole: for each trial it reads the span of log
time its analyses look at (`RunLog.window`, which decodes only the chunks that may hold the span)
and lets them go before the next trial. `analysis_span` is that span for the sample-gap count and
re-detection: from the trial's start to its end, and on to the protocol's hold after a slip (the
stick-slip window counted from a detection, which is at the latest at the trial's end).

Every analysis cuts its own part of the span with `np.searchsorted` exactly as it cut the whole
run's samples before, so the results are the same: the span holds every sample it can look at.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from rig.analysis.trials import TrialRecord
from rig.log.format import schemas
from rig.log.reading.reader import RunLog


@dataclass(frozen=True)
class TrialSamples:
    """Load-cell samples of a span of log time, sorted by it (stable), as columns."""

    times_ns: np.ndarray  # int64 log times
    forces_n: np.ndarray  # float64 tare-corrected tension
    seqs: np.ndarray  # int64 device sequence numbers, -1 where a sample has none

    def __len__(self) -> int:
        return int(self.times_ns.size)


def analysis_span(record: TrialRecord, hold_after_slip_s: float | None) -> tuple[int, int]:
    """First and last log time (inclusive) of the samples a trial's gap count and re-detection read."""
    start, end = record.result.start_time_ns, record.result.end_time_ns
    if record.ramp_start_ns is not None:
        start = min(start, record.ramp_start_ns)
    if record.unloading_ns is not None:
        end = max(end, record.unloading_ns)
    if hold_after_slip_s is not None:
        end += max(0, round(hold_after_slip_s * 1e9))
    return start, end


def loadcell_samples(log: RunLog, first_ns: int, last_ns: int) -> TrialSamples:
    """The `/rig/loadcell` samples logged from `first_ns` to `last_ns` (inclusive)."""
    frame = log.window(schemas.LOADCELL, first_ns, last_ns)
    times = frame["log_time_ns"].to_numpy(np.int64)
    forces = frame["force_n"].to_numpy(float)
    if "seq" in frame.columns:
        seqs = pd.to_numeric(frame["seq"], errors="coerce").astype("Float64")
        numbers = seqs.fillna(-1).to_numpy(np.float64).astype(np.int64)
    else:
        numbers = np.full(times.size, -1, np.int64)
    return TrialSamples(times, forces, numbers)


def trial_samples(record: TrialRecord, hold_after_slip_s: float | None) -> TrialSamples:
    """The samples of a trial's `analysis_span`, from the part it was logged in."""
    return loadcell_samples(record.part.log, *analysis_span(record, hold_after_slip_s))
