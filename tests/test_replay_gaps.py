"""`rig replay` warns per trial about load-cell samples lost on the line (gaps in the logged `seq`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.analysis import redetect as rd
from rig.analysis.gaps import sequence_gaps, trial_sample_gaps
from rig.analysis.replay_run import replay
from rig.hw.seams import LineStatsSource

PROTOCOLS = Path(__file__).resolve().parent.parent / "protocols"
SILENCE_S = 0.012  # 12 samples at the simulated cell's 1 kHz


def unplug_briefly_in_trial_2(sim) -> None:
    """At trial 2's prompt, schedule a 12 ms silence 100 ms later (during its tare): the device counts on."""
    emulator, clock = sim.devices.loadcell_emulator, sim.session.clock
    original = sim.session.operator

    class Operator:
        def confirm(self, request, keep_alive):
            if request.trial is not None and request.trial.trial_id == 2:
                emulator.inject_silence(SILENCE_S, at_ns=clock.monotonic_ns() + 100_000_000)
            original.confirm(request, keep_alive)

    sim.session.operator = Operator()


def test_samples_lost_in_a_trial_are_warned_about(sim_run):
    report, sim = sim_run(PROTOCOLS / "smoke.yaml", patch=unplug_briefly_in_trial_2)
    assert report.exit_code == 0
    load_cell = sim.session.load_cell
    assert isinstance(load_cell, LineStatsSource)
    stats = load_cell.line_stats()
    assert (stats.missing_samples, stats.sequence_gaps, stats.garbled_lines) == (12, 1, 0)

    result = replay(report.log)
    name = Path(report.log).name
    assert f"{name}: trial 2: 12 load-cell samples missing (1 sequence gap)" in result.warnings
    assert not any("trial 1:" in w for w in result.warnings)
    gaps = trial_sample_gaps(result.records)
    assert [(g.trial_id, g.missing_samples, g.sequence_gaps) for g in gaps] == [(2, 12, 1)]
    # The lost samples were never logged, so re-detection still reproduces every logged event.
    assert [r.status for r in result.redetections] == [rd.MATCH, rd.MATCH]


@pytest.mark.parametrize(
    ("seqs", "expected"),
    [
        ([], (0, 0)),
        ([5], (0, 0)),
        ([0, 1, 2, 3], (0, 0)),
        ([65534, 65535, 0, 1], (0, 0)),  # the counter wraps at 2**16
        ([65535, 2], (2, 1)),
        ([1, 2, 5, 6, 10], (5, 2)),
        ([1, -1, 7, 8], (0, 0)),  # no number: no pair to compare
        ([3, 2], (65534, 1)),  # a restarted counter reads as a long gap, as in the driver
    ],
)
def test_sequence_gaps_modulo_the_counter(seqs, expected):
    assert sequence_gaps(np.array(seqs, np.int64)) == expected
