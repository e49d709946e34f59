"""Slip detection and the ramp at the load-cell rates labs own (10/s to 2000/s; issue 21)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from model.slip_detector import (
    CREEP_MIN_SAMPLES,
    RATE_DEPENDENT_FIELDS,
    DetectorParams,
    SlipEventKind,
    detect_slips,
    params_for_rate,
    rate_defaults,
)
from rig.analysis.runlog import read_parts
from rig.cli import main
from rig.errors import InputError
from rig.inputs.protocol import for_loadcell_rate, load_protocol
from rig.inputs.rig_config import DEFAULT_LOADCELL_RATE_HZ, load_rig_config, nominal_loadcell_rate_hz
from rig.log.format import schemas
from rig.runner.ramp_speed import SAMPLING_ERROR_FRACTION, RampSpeeds
from tests.helpers import bare_protocol, shipped_block, write_joint_1_protocol

RATES_HZ = (10.0, 80.0, 320.0, 1000.0, 2000.0)
SIM_N_PER_RAD = 50.0  # the built-in simulated rig: 5000 N/m line on a 10 mm spool
PROTOCOL_DETECTOR = {"arm_threshold_n": 2.0, "drop_fraction": 0.15}  # protocols/joint_estimation.yaml


def _protocol_with_detector(tmp_path: Path, detector: dict[str, float]) -> Path:
    """A protocol of `detector` and one trial at 0.1 m on joint 1 (everything else at its default)."""
    path = tmp_path / "p.yaml"
    path.write_text(
        bare_protocol("p", [shipped_block("smoke", distances_m=[0.1], steps=None)], detector=detector)
    )
    return path


def _speeds(rate_hz: float) -> RampSpeeds:
    return RampSpeeds(fast_rad_s=1.0, slow_rad_s=0.08, rate_hz=rate_hz, n_per_rad=SIM_N_PER_RAD)


# ------------------------------------------------------------------------------------ ramp speed


def test_the_sampling_limit_leaves_the_1khz_ramp_alone_and_slows_the_slow_rates() -> None:
    fast_cell, slow_cell = _speeds(1000.0), _speeds(10.0)
    # 0.47 % of the tension per sample: 0.094·F rad/s at 1000/s, over 0.08 rad/s from 0.86 N on.
    assert fast_cell.limit_rad_s(2.0) == pytest.approx(0.188)
    assert not fast_cell.binds_at(1.0) and fast_cell.slow_at(2.0, 2.0) == 0.08
    # At 10/s it binds up to 85 N; one sample's rise is then exactly the fraction of the tension.
    assert slow_cell.binds_at(84.0) and not slow_cell.binds_at(86.0)
    speed = slow_cell.slow_at(20.0, 2.0)
    assert speed * SIM_N_PER_RAD / 10.0 == pytest.approx(SAMPLING_ERROR_FRACTION * 20.0)
    assert slow_cell.slow_at(0.5, 2.0) == slow_cell.slow_at(2.0, 2.0)  # the arm threshold as floor


@pytest.mark.parametrize("rate_hz", [10.0, 80.0, 1000.0])
def test_slow_ramp_time_is_the_integral_of_the_speed(rate_hz: float) -> None:
    speeds = _speeds(rate_hz)
    forces = np.linspace(2.0, 70.0, 200_001)
    rates_n_per_s = np.array([speeds.slow_at(f, 2.0) for f in forces[::1000]]) * SIM_N_PER_RAD
    coarse = np.interp(forces, forces[::1000], 1.0 / rates_n_per_s)
    numeric = float(np.sum((coarse[1:] + coarse[:-1]) / 2.0 * np.diff(forces)))
    assert speeds.slow_ramp_s(2.0, 70.0) == pytest.approx(numeric, rel=1e-3)
    assert speeds.slow_ramp_s(5.0, 5.0) == 0.0


def test_the_fast_phase_reaches_the_expected_slip_loads_low_edge_only_where_the_limit_binds() -> None:
    assert _speeds(1000.0).switch_n(7.0, 8.0) == 7.0  # 1 kHz: the protocol's fraction, as before
    assert _speeds(10.0).switch_n(7.0, 8.0) == 8.0
    assert _speeds(10.0).switch_n(7.0, None) == 7.0
    assert _speeds(10.0).switch_n(7.0, 6.0) == 7.0  # never lower than the protocol's switch


# -------------------------------------------------------------------------- rate-derived defaults


def test_rate_defaults_are_the_class_defaults_at_and_above_1khz() -> None:
    base = DetectorParams()
    for rate_hz in (1000.0, 2000.0):
        assert rate_defaults(rate_hz) == {name: getattr(base, name) for name in RATE_DEPENDENT_FIELDS}
        assert params_for_rate(base, (), rate_hz) == base


def test_drop_ramp_s_is_logged_only_when_set() -> None:
    assert "drop_ramp_s" not in DetectorParams().to_mapping()  # 1 kHz logs read as before
    slow = params_for_rate(DetectorParams(), (), 10.0)
    assert slow.to_mapping()["drop_ramp_s"] == pytest.approx(0.3)
    assert DetectorParams.from_mapping(slow.to_mapping()) == slow


def test_rate_defaults_below_1khz() -> None:
    low = rate_defaults(10.0)
    assert low["peak_leak_n_per_s"] == pytest.approx(0.01) and low["drop_leak_n_per_s"] == pytest.approx(0.01)
    assert low["creep_min_s"] == pytest.approx(CREEP_MIN_SAMPLES / 10.0)
    assert low["noise_window_s"] == pytest.approx(10.0)
    assert rate_defaults(80.0)["creep_min_s"] == pytest.approx(max(0.05, CREEP_MIN_SAMPLES / 80.0))
    with pytest.raises(ValueError, match="rate_hz"):
        rate_defaults(0.0)


def test_a_protocols_own_detector_fields_are_kept_at_any_rate(tmp_path: Path) -> None:
    protocol = load_protocol(_protocol_with_detector(tmp_path, {"arm_threshold_n": 2.0, "creep_min_s": 0.07}))
    assert protocol.detector_given == frozenset({"arm_threshold_n", "creep_min_s"})
    slow = for_loadcell_rate(protocol, 10.0)
    assert slow.detector.creep_min_s == 0.07 and slow.detector.peak_leak_n_per_s == pytest.approx(0.01)
    assert for_loadcell_rate(protocol, 1000.0) is protocol


def test_the_nominal_rate_is_the_cells_then_the_simulations_then_1khz(tmp_path: Path) -> None:
    assert nominal_loadcell_rate_hz(load_rig_config(None)) == 1000.0
    sim = tmp_path / "sim.yaml"
    sim.write_text("extends: simulated\nsimulation: {loadcell_rate_hz: 80}\n")
    assert nominal_loadcell_rate_hz(load_rig_config(sim)) == 80.0
    sim.write_text("extends: simulated\nloadcell: {rate_hz: 80}\nsimulation: {loadcell_rate_hz: 80}\n")
    assert nominal_loadcell_rate_hz(load_rig_config(sim)) == 80.0
    sim.write_text("extends: simulated\nloadcell: {rate_hz: 12}\nsimulation: {loadcell_rate_hz: 80}\n")
    assert nominal_loadcell_rate_hz(load_rig_config(sim)) == 12.0  # what the operator believes
    assert DEFAULT_LOADCELL_RATE_HZ == 1000.0


# ----------------------------------------------------------------------- detection at every rate


def _trace(
    rate_hz: float, peak_n: float, drop: float, seed: int, slide_s: float = 0.0
) -> tuple[list[int], list[float], int]:
    """A rate-aware ramp to `peak_n`, then a fall by `drop` of it over `slide_s` (0: sudden), then the ramp.

    Returns the sample times, the forces (5 mN noise) and the index of the first sample after the onset.
    """
    rng = np.random.default_rng(seed)
    speeds = _speeds(rate_hz)
    period_s = 1.0 / rate_hz
    forces, force = [0.0] * 20, 0.0
    force = 2.0
    while force < peak_n:
        forces.append(force)
        force += speeds.slow_at(force, 2.0) * SIM_N_PER_RAD * period_s
    # The onset falls between two samples, at a random share of the period.
    share = rng.uniform()
    onset_index = len(forces)
    rise_n = speeds.slow_at(peak_n, 2.0) * SIM_N_PER_RAD
    for i in range(int(3.0 * rate_hz) + 10):
        after_s = (i + share) * period_s
        fall = drop * peak_n * (1.0 if slide_s == 0.0 else min(1.0, after_s / slide_s))
        # While the joint slides the tension follows it down; after, the winch loads the line again.
        forces.append(peak_n - fall + rise_n * max(0.0, after_s - slide_s))
    times = [1_000_000_000 + round(i * 1e9 / rate_hz) for i in range(len(forces))]
    noisy = (np.array(forces) + rng.normal(0.0, 0.005, len(forces))).tolist()
    return times, noisy, onset_index


@pytest.mark.parametrize("rate_hz", RATES_HZ)
@pytest.mark.parametrize("drop", [0.03, 0.05, 0.20])
def test_sudden_and_small_drops_are_seen_within_2_samples_at_every_rate(rate_hz: float, drop: float) -> None:
    params = params_for_rate(DetectorParams.from_mapping(PROTOCOL_DETECTOR), PROTOCOL_DETECTOR, rate_hz)
    for seed, peak_n in enumerate((6.0, 12.0, 25.0, 50.0)):
        times, forces, onset = _trace(rate_hz, peak_n, drop, seed)
        events = detect_slips(params, times, forces)
        assert events, f"{drop:.0%} of {peak_n} N at {rate_hz}/s: not detected"
        event = events[0]
        detected = times.index(event.detection_time_ns)
        assert onset <= detected <= onset + 1, f"{rate_hz}/s: detected on sample {detected - onset + 1}"
        assert event.kind is SlipEventKind.DROP
        # The peak read is the last sample before the onset: within the ramp's rise and the noise.
        assert event.peak_force_n == pytest.approx(peak_n, rel=SAMPLING_ERROR_FRACTION, abs=0.02)


@pytest.mark.parametrize("rate_hz", [80.0, 320.0, 1000.0, 2000.0])
def test_a_slow_slide_is_creep_where_the_rate_resolves_it(rate_hz: float) -> None:
    params = params_for_rate(DetectorParams.from_mapping(PROTOCOL_DETECTOR), PROTOCOL_DETECTOR, rate_hz)
    times, forces, _ = _trace(rate_hz, 12.0, 0.05, 0, slide_s=1.0)
    events = detect_slips(params, times, forces)
    assert events and events[0].kind is SlipEventKind.CREEP


def test_at_10_per_s_a_50ms_slide_is_a_slip_not_creep() -> None:
    params = params_for_rate(DetectorParams.from_mapping(PROTOCOL_DETECTOR), PROTOCOL_DETECTOR, 10.0)
    assert params.creep_min_s == pytest.approx(CREEP_MIN_SAMPLES / 10.0)
    times, forces, onset = _trace(10.0, 12.0, 0.2, 1, slide_s=0.05)
    events = detect_slips(params, times, forces)
    assert events and events[0].kind is SlipEventKind.DROP
    assert times.index(events[0].detection_time_ns) <= onset + 1


# ---------------------------------------------------------------------------- a run at 10/s


def test_a_run_at_10_samples_per_s_ends_in_slips_with_the_slip_load_close(tmp_path: Path, capsys) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text("extends: simulated\nsimulation: {loadcell_rate_hz: 10}\n")
    protocol = write_joint_1_protocol(
        tmp_path / "p.yaml",
        "slow",
        {"fast_speed_rad_s": 1.0, "slow_speed_rad_s": 0.08, "max_force_n": 70.0},
        [0.25, 0.22, 0.25],
    )
    code = main(
        ["run", str(protocol), "--rig", str(rig), "--seed", "0", "--json", "--out", str(tmp_path / "o")]
    )
    report = json.loads(capsys.readouterr().out)
    assert code == 0 and report["completed"] == 3
    assert [t["outcome"] for t in report["trials"]] == ["slip"] * 3
    true_k = report["truth"]["k"]
    for trial in report["trials"]:
        assert trial["slip_mass_kg"] * trial["distance_m"] == pytest.approx(true_k, rel=0.3)
    assert math.isfinite(report["estimate"]["k"])
    log = read_parts(report["log"])[0].log.topic(schemas.LOG)
    assert not [m for m in log["message"] if "measured at" in m]  # 10/s configured, 10/s measured
    # The log carries the rate's detector defaults: replay re-detects every slip as it ran.
    assert main(["replay", report["log"], "--json"]) == 0
    redetection = json.loads(capsys.readouterr().out)["redetection"]
    assert redetection["matches"] == redetection["trials"] == 3


def test_a_cell_far_from_its_configured_rate_is_warned_about_once(tmp_path: Path, capsys) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text("extends: simulated\nloadcell: {rate_hz: 500}\n")  # the simulated cell streams 1000/s
    protocols = Path(__file__).resolve().parent.parent / "protocols"
    argv = ["run", str(protocols / "smoke.yaml"), "--rig", str(rig), "--json", "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    log = read_parts(report["log"])[0].log.topic(schemas.LOG)
    warnings = [m for m in log["message"] if "measured at" in m]
    assert len(warnings) == 1 and "configured 500/s" in warnings[0]


# ------------------------------------------------- the spike guard at low rates (issue 21, part 2)


def _params_at(rate_hz: float) -> DetectorParams:
    return params_for_rate(DetectorParams.from_mapping(PROTOCOL_DETECTOR), PROTOCOL_DETECTOR, rate_hz)


def _detected_sample(rate_hz: float, forces: list[float]) -> int | None:
    times = [1_000_000_000 + round(i * 1e9 / rate_hz) for i in range(len(forces))]
    events = detect_slips(_params_at(rate_hz), times, forces)
    return times.index(events[0].detection_time_ns) if events else None


# bench_rates, 10/s, seed 0, trial 8: the fast phase (5 N a sample) reaches 12.44 N, the joint slips
# at 13.33 N before the next sample, and the winch has slowed: a single-sample peak, 14 % above the
# next sample. The rest at zero load before it starts the detector (its warm-up sees the fast phase).
FAST_PHASE_OVERSHOOT = [
    0.0002,
    -0.0022,
    0.0010,
    0.0027,
    0.0014,
    2.3701,
    7.4041,
    12.4394,
    10.6947,
    11.0064,
    11.3784,
]


def test_a_single_sample_peak_on_the_fast_phase_is_a_peak_at_10_per_s() -> None:
    onset = FAST_PHASE_OVERSHOOT.index(10.6947)
    detected = _detected_sample(10.0, FAST_PHASE_OVERSHOOT)
    assert detected is not None and detected <= onset + 1
    # The 1 kHz detector (no ramp-aware guard) keeps the two-sample peak, and sees no drop.
    times = [i * 1_000_000 for i in range(len(FAST_PHASE_OVERSHOOT))]
    assert detect_slips(DetectorParams.from_mapping(PROTOCOL_DETECTOR), times, FAST_PHASE_OVERSHOOT) == []


def test_the_fast_phase_ending_on_a_plateau_is_no_drop_at_10_per_s() -> None:
    # bench_rates, 10/s: the fast phase stops at 4.3 N; the warm-up's mean increment (0.5 N a sample)
    # carried the peak by 2 samples made a 20 % "drop" of the resting line before the carry's cap.
    plateau = [-0.0013, -0.0037, 0.0038, 0.0078, 3.3753, 4.2951, 4.3101, 4.2991, 4.2993, 4.3139, 4.2943]
    assert _detected_sample(10.0, plateau + [4.30] * 20) is None


@pytest.mark.parametrize("rate_hz", [10.0, 80.0, 320.0])
def test_a_single_spike_up_or_down_on_the_slow_ramp_is_no_drop(rate_hz: float) -> None:
    speeds = _speeds(rate_hz)
    forces, force = [0.0] * 20, 2.0
    while force < 2.6:
        forces.append(force)
        force += speeds.slow_at(force, 2.0) * SIM_N_PER_RAD / rate_hz
    for index, size in ((28, 0.45), (34, -0.45)):  # over 15 % of the tension, each a single sample
        spiked = list(forces)
        spiked[index] += size
        assert _detected_sample(rate_hz, spiked) is None, f"{size:+} N at {rate_hz}/s fired"


@pytest.mark.parametrize("rate_hz", [10.0, 320.0])
def test_a_fall_caught_part_way_is_seen_on_the_next_sample(rate_hz: float) -> None:
    # The sample after the onset shows part of the fall (the slide takes 13 ms, or the onset came
    # 40 us before the sample): the two-sample guard alone waited for a third sample.
    _, forces, onset = _trace(rate_hz, 8.0, 0.2, 0)
    forces[onset] = forces[onset - 1] - 0.06  # 0.75 %: about 10 noise σ
    detected = _detected_sample(rate_hz, forces)
    assert detected is not None and detected <= onset + 1


def test_a_protocol_giving_the_drift_per_sample_is_refused_naming_the_field(tmp_path: Path) -> None:
    # The pre-release name (N per sample) is gone: the detector has one set of names.
    path = _protocol_with_detector(tmp_path, {"cusum_threshold_n": 1.0, "cusum_drift_n": 0.05})
    with pytest.raises(InputError, match=r"unknown field 'cusum_drift_n'.*cusum_drift_n_per_s"):
        load_protocol(path)


def test_the_drift_per_second_is_kept_at_every_rate(tmp_path: Path) -> None:
    protocol = load_protocol(
        _protocol_with_detector(tmp_path, {"cusum_threshold_n": 1.0, "cusum_drift_n_per_s": 50})
    )
    assert protocol.detector.cusum_drift_n_per_s == 50.0
    assert for_loadcell_rate(protocol, 1000.0) is protocol
    assert for_loadcell_rate(protocol, 10.0).detector.cusum_drift_n_per_s == 50.0
