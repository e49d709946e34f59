"""Load-cell artefacts (drift, wander, spikes, mains hum, gain creep), one at a time, through the emulator."""

from __future__ import annotations

import numpy as np
import pytest

from rig.hw.loadcell.formats import LineDecoder
from rig.inputs.rig_config import load_rig_config
from rig.sim.loadcell.artefacts import ArtefactModel
from rig.sim.loadcell.emulator import LoadCellEmulator, SignalModel
from rig.sim.loadcell.profiles import ConstantTension
from rig.sim.settings import LoadCellArtefacts
from rig.sim.simulated_rig import simulated_rig

GAIN = 80_000.0
OFFSET = 120_000.0
S = 1_000_000_000


def forces(artefacts: LoadCellArtefacts | None, seconds: float, tension_n: float = 2.5, noise: float = 0.0):
    """(times [s], decoded forces [N]) of an emulator at 1 kHz with `artefacts` and no drift of its own."""
    signal = SignalModel(
        gain_counts_per_n=GAIN, offset_counts=OFFSET, drift_counts_per_s=0.0, noise_counts=noise
    )
    model = None if artefacts is None else ArtefactModel(artefacts, seed=5)
    emulator = LoadCellEmulator(
        ConstantTension(tension_n), rate_hz=1000, signal=signal, seed=1, artefacts=model
    )
    decoder = LineDecoder(emulator.codec)
    lines = decoder.feed(b"".join(chunk for _, chunk in emulator.lines_until(round(seconds * S))))
    raws = np.array([ln.raw for ln in lines], dtype=float)
    return np.arange(len(raws)) * 1e-3, (raws - OFFSET) / GAIN, model


def test_all_off_by_default_and_the_default_rig_has_no_artefact_model() -> None:
    assert not LoadCellArtefacts().active
    rig = simulated_rig(load_rig_config(), seed=0)
    assert rig.devices.loadcell_emulator.artefacts is None
    assert rig.devices.world.preset.loadcell_noise_n == 0.005


def test_offset_drift_is_a_straight_line() -> None:
    t, f, _ = forces(LoadCellArtefacts(drift_n_per_s=0.01), 10.0)
    slope, intercept = np.polyfit(t, f, 1)
    assert slope == pytest.approx(0.01, rel=1e-3) and intercept == pytest.approx(2.5, abs=1e-4)


def test_zero_wander_is_a_random_walk_of_the_stated_size() -> None:
    _, f, _ = forces(LoadCellArtefacts(wander_n_per_sqrt_s=0.02), 20.0)
    steps = np.diff(f)
    assert steps.std() == pytest.approx(0.02 * np.sqrt(1e-3), rel=0.05)
    assert abs(np.corrcoef(steps[:-1], steps[1:])[0, 1]) < 0.05  # independent increments


def test_spikes_are_single_samples_at_the_stated_rate_and_size() -> None:
    _, f, model = forces(LoadCellArtefacts(spike_rate_per_s=5.0, spike_n=0.4), 60.0)
    deviation = f - 2.5
    spiky = np.flatnonzero(np.abs(deviation) > 1e-4)
    assert model is not None and len(spiky) == model.spikes
    assert len(spiky) == pytest.approx(300, abs=4 * np.sqrt(300))
    assert np.all(np.diff(spiky) > 1)  # never two in a row at this rate (single-sample spikes)
    sizes = np.abs(deviation[spiky])
    assert sizes.min() >= 0.2 - 1e-4 and sizes.max() <= 0.4 + 1e-4
    assert 0.3 < np.mean(deviation[spiky] > 0) < 0.7  # either sign


def test_mains_hum_is_a_sine_at_its_frequency() -> None:
    _, f, _ = forces(LoadCellArtefacts(hum_n=0.03, hum_hz=50.0), 2.0, noise=400.0)
    spectrum = np.abs(np.fft.rfft(f - f.mean())) * 2 / len(f)
    frequencies = np.fft.rfftfreq(len(f), 1e-3)
    peak = int(np.argmax(spectrum))
    assert frequencies[peak] == pytest.approx(50.0, abs=0.5)
    assert spectrum[peak] == pytest.approx(0.03, rel=0.05)


def test_gain_creep_approaches_its_fraction_with_its_time_constant() -> None:
    t, f, _ = forces(LoadCellArtefacts(gain_creep_fraction=0.01, gain_creep_time_constant_s=2.0), 10.0, 20.0)
    expected = 20.0 * (1 + 0.01 * (1 - np.exp(-t / 2.0)))
    assert np.abs(f - expected).max() < 2e-5


def test_artefacts_use_their_own_stream_so_the_white_noise_is_unchanged() -> None:
    _, plain, _ = forces(None, 1.0, noise=400.0)
    _, hummed, _ = forces(LoadCellArtefacts(hum_n=0.05, spike_rate_per_s=3.0, spike_n=0.2), 1.0, noise=400.0)
    t = np.arange(len(plain)) * 1e-3
    difference = hummed - plain
    without_spikes = np.abs(difference) < 0.06
    assert without_spikes.sum() >= len(plain) - 10
    # What is left is the hum alone (up to a count of quantisation): the noise draws are the same.
    residual = difference[without_spikes]
    fit = np.linalg.lstsq(
        np.column_stack([np.sin(2 * np.pi * 50 * t), np.cos(2 * np.pi * 50 * t)])[without_spikes],
        residual,
        rcond=None,
    )
    assert (
        np.abs(
            residual
            - fit[0][0] * np.sin(2 * np.pi * 50 * t[without_spikes])
            - fit[0][1] * np.cos(2 * np.pi * 50 * t[without_spikes])
        ).max()
        <= 1.5 / GAIN
    )


def test_same_seed_same_artefacts() -> None:
    artefacts = LoadCellArtefacts(wander_n_per_sqrt_s=0.01, spike_rate_per_s=2.0, spike_n=0.3, hum_n=0.01)
    assert np.array_equal(forces(artefacts, 2.0, noise=50.0)[1], forces(artefacts, 2.0, noise=50.0)[1])


def test_ranges_are_checked() -> None:
    with pytest.raises(ValueError, match="hum_hz"):
        LoadCellArtefacts(hum_hz=0.0)
    with pytest.raises(ValueError, match="spike_rate_per_s"):
        LoadCellArtefacts(spike_rate_per_s=-1.0)
