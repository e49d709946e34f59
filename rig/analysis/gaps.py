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

from rig.analysis.samples import TrialSamples, trial_samples
from rig.analysis.trials import TrialRecord
from rig.hw.loadcell.formats import SEQ_MODULUS


@dataclass(frozen=True)
class SampleGaps:
    """The load-cell samples missing in one trial."""

    trial_id: int
    part: str
    missing_samples: int
    sequence_gaps: int


def trial_gaps(record: TrialRecord, samples: TrialSamples) -> SampleGaps | None:
    """The trial's gaps in `samples` (which must hold its span from start to end), or None without any."""
    times = samples.times_ns
    lo = int(np.searchsorted(times, record.result.start_time_ns, side="left"))
    hi = int(np.searchsorted(times, record.result.end_time_ns, side="right"))
    missing, gaps = sequence_gaps(samples.seqs[lo:hi])
    return SampleGaps(record.trial_id, record.part.name, missing, gaps) if gaps else None


def trial_sample_gaps(records: Sequence[TrialRecord]) -> list[SampleGaps]:
    """The trials whose logged load-cell `seq` has gaps, in the order of `records` (read trial by trial)."""
    found = []
    for record in records:
        gaps = trial_gaps(record, trial_samples(record, None))
        if gaps is not None:
            found.append(gaps)
    return found


def sequence_gaps(seqs: np.ndarray) -> tuple[int, int]:
    """(samples missing, gaps) between consecutive sequence numbers (-1 for none), modulo 2**16."""
    numbered = (seqs[1:] >= 0) & (seqs[:-1] >= 0)
    skipped = (seqs[1:] - seqs[:-1] - 1) % SEQ_MODULUS
    gaps = skipped[numbered & (skipped != 0)]
    return int(gaps.sum()), int(gaps.size)


def gap_warning(gaps: SampleGaps) -> str:
    """The warning for a trial with missing load-cell samples."""
    return (
        f"{gaps.part}: trial {gaps.trial_id}: {gaps.missing_samples} load-cell samples missing "
        f"({gaps.sequence_gaps} sequence gap{'s' if gaps.sequence_gaps != 1 else ''})"
    )


def sample_gap_warnings(records: Sequence[TrialRecord]) -> list[str]:
    """One warning per trial with missing load-cell samples."""
    return [gap_warning(g) for g in trial_sample_gaps(records)]
