"""What a real load cell adds to the line tension besides white noise: drift, wander, spikes, hum, gain creep.

The one definition of the artefacts (`rig.sim.settings.LoadCellArtefacts` documents the formula and
the parameters). `ArtefactModel.apparent_tension_n` turns the true tension at a sample into the
tension the cell's bridge reports; the emulator (`LoadCellEmulator`, both its in-process port and
its pty process) converts that to ADC counts with its white noise and quantisation. The model is
stateful (the zero's random walk) and must see every sample once, in order. Its random draws come
from their own stream, so switching an artefact on changes neither the white noise nor the world.
"""

from __future__ import annotations

import math
import random

from rig.sim.settings import LoadCellArtefacts


class ArtefactModel:
    """Applies `LoadCellArtefacts` sample by sample; see the module docstring."""

    def __init__(self, artefacts: LoadCellArtefacts, seed: int) -> None:
        self.artefacts = artefacts
        self._rng = random.Random(seed)
        self._hum_phase_rad = self._rng.random() * math.tau if artefacts.hum_n else 0.0
        self._wander_n = 0.0
        self._last_s: float | None = None
        self.spikes = 0  # how many spikes were added (tests, benchmarks)

    def apparent_tension_n(self, tension_n: float, elapsed_s: float, sample_period_s: float) -> float:
        """The tension the bridge reports for `tension_n` at `elapsed_s` since power-on."""
        a = self.artefacts
        rng = self._rng
        value = tension_n
        if a.gain_creep_fraction:
            value *= 1.0 + a.gain_creep_fraction * (1.0 - math.exp(-elapsed_s / a.gain_creep_time_constant_s))
        value += a.drift_n_per_s * elapsed_s
        if a.wander_n_per_sqrt_s:
            dt_s = sample_period_s if self._last_s is None else max(0.0, elapsed_s - self._last_s)
            self._wander_n += a.wander_n_per_sqrt_s * math.sqrt(dt_s) * rng.gauss(0.0, 1.0)
            value += self._wander_n
        self._last_s = elapsed_s
        if a.hum_n:
            value += a.hum_n * math.sin(math.tau * a.hum_hz * elapsed_s + self._hum_phase_rad)
        if a.spike_n and a.spike_rate_per_s and rng.random() < a.spike_rate_per_s * sample_period_s:
            size = a.spike_n * (0.5 + 0.5 * rng.random())
            value += size if rng.random() < 0.5 else -size
            self.spikes += 1
        return value
