"""Load-cell samples lost during each trial, from the gaps in the logged `/rig/loadcell` `seq`.

The device numbers its samples (`rig-lc1`, modulo 2**16); a sample whose line was lost on the wire,
garbled or failed its checksum never reaches the log, and leaves a gap in the numbers. Only
consecutive logged samples that both carry a number count (formats without one give nothing), and
only pairs inside the trial's span (its start and end times). Like the driver's own count, a gap
longer than 2**16 samples is under-counted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rig.analysis.trials import TrialRecord
from rig.hw.loadcell.formats import SEQ_MODULUS
from rig.log import schemas


@dataclass(frozen=True)
class SampleGaps:
    """The load-cell samples missing in one trial."""

    trial_id: int
    part: str
    missing_samples: int
    sequence_gaps: int


def trial_sample_gaps(records: Sequence[TrialRecord]) -> list[SampleGaps]:
    """The trials whose logged load-cell `seq` has gaps, in the order of `records`."""
    columns: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    found = []
    for record in records:
        key = id(record.part)
        if key not in columns:
            columns[key] = _seq_column(record.part.log.topic(schemas.LOADCELL))
        times, seqs = columns[key]
        lo = int(np.searchsorted(times, record.result.start_time_ns, side="left"))
        hi = int(np.searchsorted(times, record.result.end_time_ns, side="right"))
        missing, gaps = sequence_gaps(seqs[lo:hi])
        if gaps:
            found.append(SampleGaps(record.trial_id, record.part.name, missing, gaps))
    return found


def sequence_gaps(seqs: np.ndarray) -> tuple[int, int]:
    """(samples missing, gaps) between consecutive sequence numbers (-1 for none), modulo 2**16."""
    numbered = (seqs[1:] >= 0) & (seqs[:-1] >= 0)
    skipped = (seqs[1:] - seqs[:-1] - 1) % SEQ_MODULUS
    gaps = skipped[numbered & (skipped != 0)]
    return int(gaps.sum()), int(gaps.size)


def sample_gap_warnings(records: Sequence[TrialRecord]) -> list[str]:
    """One warning per trial with missing load-cell samples."""
    return [
        f"{g.part}: trial {g.trial_id}: {g.missing_samples} load-cell samples missing "
        f"({g.sequence_gaps} sequence gap{'s' if g.sequence_gaps != 1 else ''})"
        for g in trial_sample_gaps(records)
    ]


def _seq_column(frame: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Log times and sequence numbers (-1 where there is none) of a `/rig/loadcell` frame."""
    times = frame["log_time_ns"].to_numpy(np.int64)
    if "seq" not in frame.columns:
        return times, np.full(times.size, -1, np.int64)
    seqs = pd.to_numeric(frame["seq"], errors="coerce").astype("Float64")
    return times, seqs.fillna(-1).to_numpy(np.float64).astype(np.int64)
