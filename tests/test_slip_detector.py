"""Slip detector: synthetic traces with known slips, noise robustness, re-arm, parameters, purity."""

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from model.slip_detector import (
    DetectorParams,
    DetectorPhase,
    DetectorState,
    SlipEvent,
    detect_slips,
    detector_init,
    detector_step,
    further_drops,
    noise_sigma_n,
)

T0_NS = 1_700_000_000_000_000_000  # an epoch-like start: detection must not depend on absolute time


def piecewise_trace(knots, rate_hz=1000.0, noise_n=0.0, seed=0):
    """Sampled piecewise-linear force through (time_s, force_n) knots, with Gaussian noise."""
    knot_t = np.array([k[0] for k in knots])
    knot_f = np.array([k[1] for k in knots])
    count = round((knot_t[-1] - knot_t[0]) * rate_hz) + 1
    t_s = knot_t[0] + np.arange(count) / rate_hz
    forces = np.interp(t_s, knot_t, knot_f)
    if noise_n:
        forces = forces + np.random.default_rng(seed).normal(0.0, noise_n, count)
    times_ns = [T0_NS + round(t * 1e9) for t in t_s]
    return times_ns, [float(f) for f in forces]


def slip_knots(start_s=0.0, peak_n=15.0, ramp_n_per_s=5.0, after_n=9.0, drop_s=0.02):
    """Ramp from 0 to the peak, a quick drop (the slip), hold, then unload to 0."""
    t_peak = start_s + peak_n / ramp_n_per_s
    return [
        (start_s, 0.0),
        (t_peak, peak_n),
        (t_peak + drop_s, after_n),
        (t_peak + drop_s + 0.5, after_n),
        (t_peak + drop_s + 1.0, 0.0),
    ]


LEGACY = {"noise_k": None, "creep_k": None}  # only the percentage-drop, slope and CUSUM triggers


def ns(t_s):
    return T0_NS + round(t_s * 1e9)


def test_ramp_and_drop_fires_once_with_the_peak():
    times, forces = piecewise_trace(slip_knots(), noise_n=0.0)
    events = detect_slips(DetectorParams(**LEGACY), times, forces)
    assert len(events) == 1
    event = events[0]
    assert event.peak_force_n == pytest.approx(15.0, abs=1e-9)
    assert event.peak_time_ns == ns(3.0) == event.onset_time_ns
    assert event.trigger == "drop"
    # The drop falls 300 N/s; 15 % of 15 N = 2.25 N is reached 7.5 ms after the peak, and the
    # spike-robust comparison (max of the last two samples) sees it one sample later.
    assert event.detection_time_ns == ns(3.009)
    assert event.force_after_n == pytest.approx(15.0 - 0.3 * 9, abs=1e-9)
    assert event.drop_fraction == pytest.approx(2.7 / 15.0, abs=1e-9)


@pytest.mark.parametrize("seed", range(20))
def test_ramp_and_drop_with_load_cell_noise(seed):
    # Includes the unloading ramp through the arm threshold after the slip: noise there must not
    # re-arm the detector (seed 5 did, before the re-arm level got its hysteresis band).
    times, forces = piecewise_trace(slip_knots(), noise_n=0.02, seed=seed)
    params = DetectorParams(arm_threshold_n=1.5, drop_fraction=0.15, min_drop_n=0.2)
    events = detect_slips(params, times, forces)
    assert len(events) == 1
    event = events[0]
    assert event.peak_force_n == pytest.approx(15.0, abs=0.1)
    assert abs(event.peak_time_ns - ns(3.0)) <= 20_000_000  # noise can move the peak by a few samples
    assert ns(3.0) < event.detection_time_ns <= ns(3.02)
    assert event.onset_time_ns <= event.detection_time_ns


def test_noise_below_the_arm_threshold_never_fires():
    times, forces = piecewise_trace([(0.0, 0.5), (20.0, 0.5)], noise_n=0.1, seed=3)
    params = DetectorParams(arm_threshold_n=1.0, drop_fraction=0.05, min_drop_n=0.0, slope_n_per_s=1.0,
                            cusum_threshold_n=0.01, cusum_drift_n_per_s=0.0)  # fmt: skip
    assert max(forces) < 1.0
    state = detector_init(params)
    for t, f in zip(times, forces, strict=True):
        state, event = detector_step(params, state, t, f)
        assert event is None
        assert state.phase is DetectorPhase.IDLE


@pytest.mark.parametrize(
    "params",
    [
        DetectorParams(arm_threshold_n=1.5, drop_fraction=0.15, min_drop_n=0.2),
        DetectorParams(
            arm_threshold_n=1.5,
            drop_fraction=0.15,
            min_drop_n=0.2,
            slope_n_per_s=50.0,
            slope_window_s=0.02,
            cusum_threshold_n=1.0,
            cusum_drift_n_per_s=50.0,
        ),
    ],
    ids=["drop", "all-triggers"],
)
def test_noise_after_arming_does_not_false_fire(params):
    # Ramp to 15 N and hold for 20 s with sigma = 0.02 N: ~20000 armed samples of noise.
    times, forces = piecewise_trace([(0.0, 0.0), (3.0, 15.0), (23.0, 15.0)], noise_n=0.02, seed=11)
    assert detect_slips(params, times, forces) == []


def test_slow_unloading_fires_drop_but_not_slope():
    # Tension relaxing at 2 N/s is no slip by slope; by drop fraction it is (the drop is real).
    knots = [(0.0, 0.0), (3.0, 15.0), (6.0, 9.0)]
    times, forces = piecewise_trace(knots, noise_n=0.0)
    slope_only = DetectorParams(drop_fraction=None, slope_n_per_s=50.0, **LEGACY)
    assert detect_slips(slope_only, times, forces) == []
    (event,) = detect_slips(DetectorParams(drop_fraction=0.15, **LEGACY), times, forces)
    assert event.trigger == "drop"


def test_slope_trigger_fires_before_the_drop_fraction():
    times, forces = piecewise_trace(slip_knots(), noise_n=0.0)
    params = DetectorParams(
        drop_fraction=0.15, min_drop_n=0.2, slope_n_per_s=50.0, slope_window_s=0.01, **LEGACY
    )
    (event,) = detect_slips(params, times, forces)
    assert "slope" in event.trigger
    assert event.onset_time_ns == event.peak_time_ns == ns(3.0)
    # A 10 ms window straddling the corner reaches -50 N/s within a couple of samples.
    assert ns(3.0) < event.detection_time_ns < ns(3.006)


def test_cusum_trigger_and_its_onset():
    times, forces = piecewise_trace(slip_knots(), noise_n=0.02, seed=5)
    params = DetectorParams(
        arm_threshold_n=1.5,
        drop_fraction=None,
        min_drop_n=0.2,
        cusum_threshold_n=1.0,
        cusum_drift_n_per_s=50.0,
        **LEGACY,
    )
    (event,) = detect_slips(params, times, forces)
    assert event.trigger == "cusum"
    assert abs(event.onset_time_ns - ns(3.0)) <= 5_000_000
    assert event.onset_time_ns < event.detection_time_ns <= ns(3.01)


def test_stick_slip_fires_once_per_drop_when_rearmed():
    knots = []
    peaks = [12.0, 14.0, 13.0]
    t = 0.0
    for peak in peaks:
        knots += [
            (t, 0.3),
            (t + peak / 10.0, peak),
            (t + peak / 10.0 + 0.02, 0.3),
            (t + peak / 10.0 + 0.3, 0.3),
        ]
        t += peak / 10.0 + 0.31
    times, forces = piecewise_trace(knots, noise_n=0.02, seed=2)
    events = detect_slips(DetectorParams(arm_threshold_n=1.0), times, forces)
    assert [round(e.peak_force_n) for e in events] == [12, 14, 13]


def test_partial_drops_need_a_higher_rearm_level():
    # Stick-slip that never unloads below 6 N: re-arm at 8 N to see every drop.
    knots = [
        (0.0, 0.0),
        (1.0, 10.0),
        (1.02, 7.0),
        (1.3, 11.0),
        (1.32, 7.5),
        (1.6, 12.0),
        (1.62, 7.0),
        (1.9, 7.0),
    ]
    times, forces = piecewise_trace(knots, noise_n=0.0)
    assert len(detect_slips(DetectorParams(arm_threshold_n=1.0), times, forces)) == 1
    events = detect_slips(DetectorParams(arm_threshold_n=1.0, rearm_below_n=8.0), times, forces)
    assert [e.peak_force_n for e in events] == pytest.approx([10.0, 11.0, 12.0])


def test_latched_detector_ignores_a_second_dip_until_rearmed():
    knots = [(0.0, 0.0), (2.0, 10.0), (2.02, 7.0), (2.2, 9.5), (2.22, 5.0), (2.5, 0.0)]
    times, forces = piecewise_trace(knots)
    events = detect_slips(DetectorParams(), times, forces)
    assert len(events) == 1 and events[0].peak_force_n == pytest.approx(10.0)


def test_detect_slips_equals_stepping_by_hand():
    knots = slip_knots() + [(k[0] + 5.0, k[1]) for k in slip_knots(peak_n=12.0)][1:]
    times, forces = piecewise_trace(knots, noise_n=0.02, seed=9)
    params = DetectorParams(slope_n_per_s=80.0, cusum_threshold_n=1.0)
    state = detector_init(params)
    by_hand: list[SlipEvent] = []
    for t, f in zip(times, forces, strict=True):
        state, event = detector_step(params, state, t, f)
        if event is not None:
            by_hand.append(event)
    assert len(by_hand) == 2
    assert detect_slips(params, times, forces) == by_hand
    assert detect_slips(params, np.array(times, dtype=np.int64), np.array(forces)) == by_hand


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(st.tuples(st.integers(0, 5_000_000), st.floats(-5.0, 30.0)), min_size=1, max_size=300),
    drop=st.floats(0.05, 0.9),
    slope=st.one_of(st.none(), st.floats(1.0, 500.0)),
    cusum=st.one_of(st.none(), st.floats(0.1, 5.0)),
)
def test_events_are_consistent_on_arbitrary_signals(steps, drop, slope, cusum):
    params = DetectorParams(drop_fraction=drop, slope_n_per_s=slope, cusum_threshold_n=cusum)
    times = list(np.cumsum([dt for dt, _ in steps]) + T0_NS)
    forces = [f for _, f in steps]
    state = detector_init(params)
    events = []
    for t, f in zip(times, forces, strict=True):
        before = state
        state, event = detector_step(params, state, int(t), f)
        if event is not None:
            events.append(event)
            assert before.phase is DetectorPhase.ARMED and state.phase is DetectorPhase.LATCHED
            assert event.detection_time_ns == t and event.force_after_n == f
            assert event.onset_time_ns <= event.detection_time_ns
            assert event.peak_time_ns <= event.detection_time_ns
            if set(event.trigger.split("+")) <= {"drop", "slope", "cusum"}:
                assert event.peak_force_n - event.force_after_n >= params.min_drop_n
            assert event.kind in ("drop", "creep")
            assert event.peak_force_n >= params.arm_threshold_n
            assert math.isclose(event.drop_fraction, (event.peak_force_n - f) / event.peak_force_n)
    assert detect_slips(params, times, forces) == events


def test_rejects_time_going_backwards_and_non_finite_force():
    params = DetectorParams()
    state, _ = detector_step(params, detector_init(params), 1000, 0.0)
    with pytest.raises(ValueError, match="earlier than the previous sample"):
        detector_step(params, state, 999, 0.0)
    for bad in (math.nan, math.inf):
        with pytest.raises(ValueError, match="allowed: finite"):
            detector_step(params, state, 2000, bad)
    with pytest.raises(ValueError, match="one force per time"):
        detect_slips(params, [1, 2], [0.0])


def test_state_is_immutable_and_steps_are_pure():
    params = DetectorParams()
    state = detector_init(params)
    assert state == DetectorState()
    armed, _ = detector_step(params, state, 10, 5.0)
    again, _ = detector_step(params, state, 10, 5.0)
    assert armed == again and state == DetectorState()
    with pytest.raises(AttributeError):
        armed.peak_force_n = 1.0  # type: ignore[misc]


# ---- parameters ------------------------------------------------------------------------------


def test_params_round_trip_through_a_mapping():
    params = DetectorParams(arm_threshold_n=2.0, drop_fraction=0.2, slope_n_per_s=40.0, cusum_threshold_n=1.5)
    mapping = params.to_mapping()
    assert mapping["drop_fraction"] == 0.2 and mapping["rearm_below_n"] is None
    assert DetectorParams.from_mapping(mapping) == params
    assert list(mapping) == [
        "arm_threshold_n", "drop_fraction", "min_drop_n", "slope_n_per_s", "slope_window_s",
        "cusum_threshold_n", "cusum_drift_n_per_s", "rearm_below_n", "noise_k", "noise_floor_n",
        "noise_window_s", "trend_window_s", "peak_leak_n_per_s", "creep_k", "creep_drift_n_per_s",
        "creep_min_s", "spike_samples", "train_k", "drop_leak_n_per_s", "warmup_s", "train_window_s",
    ]  # fmt: skip


def test_params_from_strings_and_overrides():
    params = DetectorParams.from_mapping(
        {"drop_fraction": "0.25", "slope_n_per_s": "none", "arm_threshold_n": 3}
    )
    assert params.drop_fraction == 0.25 and params.slope_n_per_s is None and params.arm_threshold_n == 3.0
    changed = params.with_overrides(["drop_fraction=0.3", "cusum_threshold_n = 2"])
    assert changed.drop_fraction == 0.3 and changed.cusum_threshold_n == 2.0
    assert changed.arm_threshold_n == 3.0


@pytest.mark.parametrize(
    ("mapping", "message"),
    [
        ({"drop_fraction": 1.0}, "detector: drop_fraction = 1.0; allowed: a number in (0, 1) or none"),
        ({"drop_fraction": 0}, "drop_fraction = 0; allowed"),
        ({"arm_threshold_n": -1}, "arm_threshold_n = -1; allowed: a number in (0, 1e+06]"),
        ({"arm_threshold_n": None}, "arm_threshold_n is required"),
        ({"min_drop_n": "abc"}, "min_drop_n = 'abc' is not a number"),
        ({"slope_window_s": math.nan}, "slope_window_s = nan"),
        ({"cusum_drift_n_per_s": True}, "cusum_drift_n_per_s = True"),
        # one set of names: the per-sample drift of the pre-release detector is no field of it
        ({"cusum_drift_n": 0.05}, "unknown field 'cusum_drift_n' (did you mean 'cusum_drift_n_per_s'?)"),
        ({"drop_frac": 0.2}, "unknown field 'drop_frac' (did you mean 'drop_fraction'?); allowed: arm_"),
        ({"drop_fraction": None, "noise_k": None, "creep_k": "off"}, "no trigger enabled"),
        ({"noise_k": 0}, "noise_k = 0; allowed: a number in (0, 1000] or none"),
        ({"noise_floor_n": None}, "noise_floor_n is required"),
        ({"spike_samples": 1.5}, "spike_samples = 1.5; allowed: 1 or 2"),
    ],
    ids=["drop-1", "drop-0", "arm-neg", "arm-none", "nan-str", "nan", "bool", "old-name", "misspelt",
         "no-trigger", "noise-0", "floor-none", "spikes-1.5"],
)  # fmt: skip
def test_params_errors_name_source_field_and_range(mapping, message):
    with pytest.raises(ValueError) as excinfo:
        DetectorParams.from_mapping(mapping, source="proto.yaml: detector")
    assert message in str(excinfo.value)
    assert str(excinfo.value).startswith("proto.yaml: detector: ")


def test_params_direct_construction_is_validated_too():
    with pytest.raises(ValueError, match="drop_fraction"):
        DetectorParams(drop_fraction=1.5)
    with pytest.raises(ValueError, match="key=value"):
        DetectorParams().with_overrides(["drop_fraction"])
    with pytest.raises(ValueError, match="expected a mapping"):
        DetectorParams.from_mapping([("drop_fraction", 0.2)])  # type: ignore[arg-type]


# ---- noise-scaled drop and creep triggers -----------------------------------------------------


def ramp_then(peak_n, after, noise_n, seed, ramp_n_per_s=5.0, rate_hz=1000.0):
    """Ramp 0 -> peak at `ramp_n_per_s`, then the knots `after` as (seconds after the peak, force)."""
    t_peak = peak_n / ramp_n_per_s
    knots = [(0.0, 0.0), (t_peak, peak_n)] + [(t_peak + dt, f) for dt, f in after]
    return t_peak, *piecewise_trace(knots, rate_hz=rate_hz, noise_n=noise_n, seed=seed)


@pytest.mark.parametrize("peak_n", [2.5, 15.0])
@pytest.mark.parametrize("seed", range(5))
def test_a_three_percent_drop_fires_on_a_5_mn_cell(peak_n, seed):
    after = [(0.001, 0.97 * peak_n), (0.5, 0.97 * peak_n)]
    t_peak, times, forces = ramp_then(peak_n, after, noise_n=0.005, seed=seed)
    assert detect_slips(DetectorParams(**LEGACY), times, forces) == []  # 3 % < drop_fraction
    (event,) = detect_slips(DetectorParams(), times, forces)
    assert event.kind == "drop" and "noise" in event.trigger
    assert ns(t_peak) < event.detection_time_ns <= ns(t_peak + 0.002)  # within 2 samples
    assert abs(event.onset_time_ns - ns(t_peak)) <= 3_000_000
    assert event.peak_force_n == pytest.approx(peak_n, abs=0.02)


@pytest.mark.parametrize("seed", range(5))
def test_creep_fires_as_creep_with_the_slip_load(seed):
    # The tension stops rising and sags 10 % over 1 s (the joint slides while the winch reels).
    t_peak, times, forces = ramp_then(10.0, [(1.0, 9.0), (1.5, 9.0)], noise_n=0.005, seed=seed)
    assert detect_slips(DetectorParams(**LEGACY), times, forces) == []
    (event,) = detect_slips(DetectorParams(), times, forces)
    assert event.kind == "creep" and "creep" in event.trigger
    assert event.peak_force_n == pytest.approx(10.0, rel=0.01)
    assert abs(event.onset_time_ns - ns(t_peak)) <= 20_000_000
    assert event.detection_time_ns <= ns(t_peak + 0.2)


def test_noise_estimate_tracks_the_load_cell_noise():
    params = DetectorParams()
    _, times, forces = ramp_then(15.0, [(5.0, 15.0)], noise_n=0.005, seed=4)
    state = detector_init(params)
    for t, f in zip(times, forces, strict=True):
        state, _ = detector_step(params, state, t, f)
    assert state.phase is DetectorPhase.ARMED
    assert noise_sigma_n(params, state) == pytest.approx(0.005, rel=0.15)
    assert noise_sigma_n(params, detector_init(params)) == params.noise_floor_n


@pytest.mark.parametrize("seed", range(3))
def test_no_false_alarm_on_a_hold_with_drift_and_spikes(seed):
    # 2.5 N hold for 60 s with 5 mN noise, a 0.2 N sinusoidal drift, and 10 single-sample spikes.
    count = 60_000
    t_s = np.arange(count) / 1000.0
    rng = np.random.default_rng(seed)
    forces = 2.5 + 0.1 * np.sin(2 * np.pi * t_s / 20.0) + rng.normal(0.0, 0.005, count)
    forces[rng.integers(100, count, 10)] += rng.choice([-0.15, 0.15], 10)  # 30 σ; two would pass 15 %
    ramp_t = np.arange(500) / 1000.0
    forces = np.concatenate([2.5 * ramp_t / 0.5 + rng.normal(0.0, 0.005, 500), forces])
    times = [T0_NS + i * 1_000_000 for i in range(len(forces))]
    assert detect_slips(DetectorParams(), times, [float(f) for f in forces]) == []


def test_event_kind_round_trips_through_the_slip_message():
    from rig.records import SlipMessage

    event = SlipEvent(1, 2, 1, 5.0, 4.0, 0.2, "creep", kind="creep")
    message = SlipMessage(trial_id=3, event=event, detector=DetectorParams().to_mapping())
    payload = message.to_payload()
    assert payload["kind"] == "creep"
    assert SlipMessage.from_payload(payload).event == event


def test_the_single_sample_drop_fires_one_sample_before_the_spike_robust_one():
    single = DetectorParams(
        noise_k=None, creep_k=None, spike_samples=1.0, train_k=None, drop_leak_n_per_s=0.0
    )
    times, forces = piecewise_trace(slip_knots())
    (event,) = detect_slips(single, times, forces)
    assert event.detection_time_ns == ns(3.008) and event.trigger == "drop"
    # A protocol naming only some fields gets the current defaults.
    assert DetectorParams.from_mapping({"drop_fraction": 0.15}).noise_k == 10.0


# ---- stick-slip trains: further drops counted while latched -----------------------------------


def first_event_and_hold(params, times, forces, hold_s=0.2):
    """The first event, and `further_drops` over the samples up to `hold_s` after its detection."""
    state = detector_init(params)
    for i, (t, f) in enumerate(zip(times, forces, strict=True)):
        state, event = detector_step(params, state, t, f)
        if event is not None:
            end = event.detection_time_ns + ns(hold_s) - T0_NS
            hold = [(u, g) for u, g in zip(times[i + 1 :], forces[i + 1 :], strict=True) if u <= end]
            _, drops = further_drops(params, state, [u for u, _ in hold], [g for _, g in hold])
            return event, drops
    return None, 0


@pytest.mark.parametrize("seed", range(5))
def test_drops_after_the_first_are_counted_as_a_train(seed):
    # 10 % first drop, then two more of 4 % of the peak 30 and 70 ms later (no re-tension).
    after = [(0.001, 9.0), (0.030, 9.0), (0.031, 8.6), (0.070, 8.6), (0.071, 8.2), (0.3, 8.2)]
    _, times, forces = ramp_then(10.0, after, noise_n=0.005, seed=seed)
    event, drops = first_event_and_hold(DetectorParams(), times, forces)
    assert event is not None and event.kind == "drop" and drops == 2
    assert detect_slips(DetectorParams(), times, forces) == [event]  # the count changes no event


@pytest.mark.parametrize("seed", range(5))
def test_a_drop_after_the_line_re_tensions_is_counted(seed):
    after = [(0.001, 9.0), (0.050, 9.4), (0.051, 8.8), (0.3, 8.8)]
    _, times, forces = ramp_then(10.0, after, noise_n=0.005, seed=seed)
    assert first_event_and_hold(DetectorParams(), times, forces)[1] == 1


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("sag_s", [0.05, 0.2, 1.0])
def test_a_sag_that_goes_on_after_the_event_is_no_train(seed, sag_s):
    # Sudden 5 % drop, then the tension keeps sagging another 10 % (the joint slides on).
    after = [(0.001, 9.5), (0.001 + sag_s, 8.5), (0.5, 8.5)]
    _, times, forces = ramp_then(10.0, after, noise_n=0.005, seed=seed)
    assert first_event_and_hold(DetectorParams(), times, forces, hold_s=0.4)[1] == 0


@pytest.mark.parametrize("seed", range(5))
def test_a_single_drop_with_noise_and_spikes_is_no_train(seed):
    _, times, forces = ramp_then(10.0, [(0.001, 8.5), (0.5, 8.5)], noise_n=0.005, seed=seed)
    forces[2100] += 0.3  # single-sample spikes in the hold
    forces[2200] -= 0.3
    assert first_event_and_hold(DetectorParams(), times, forces, hold_s=0.4)[1] == 0


def test_no_train_is_counted_without_train_k():
    after = [(0.001, 8.0), (0.030, 8.0), (0.031, 7.0), (0.3, 7.0)]
    _, times, forces = ramp_then(10.0, after, noise_n=0.005, seed=0)
    off = replace(DetectorParams(), train_k=None)
    assert first_event_and_hold(off, times, forces)[1] == 0
    assert first_event_and_hold(DetectorParams(), times, forces)[1] == 1


def test_a_mapping_of_the_pre_release_detector_is_refused_naming_the_field():
    # Its logged mapping named the drift per sample; the detector has one set of names now.
    old = {"arm_threshold_n": 1.0, "drop_fraction": 0.15, "cusum_drift_n": 0.05}
    with pytest.raises(ValueError, match="unknown field 'cusum_drift_n'"):
        DetectorParams.from_mapping(old)
    with pytest.raises(ValueError, match="unknown field 'cusum_drift_n'"):
        DetectorParams().with_overrides(["cusum_drift_n=0"])


def test_the_cusum_drift_is_per_second_at_every_rate():
    # A 0.3 N sag over 0.3 s, sampled at 1000/s and at 100/s: the same CUSUM at the end (1 N/s
    # net of a 0.5 N/s drift allowance is 0.15 N), where a per-sample drift differed 10×.
    params = DetectorParams(arm_threshold_n=0.5, drop_fraction=None, noise_k=None, creep_k=None,
                            cusum_threshold_n=0.14, cusum_drift_n_per_s=0.5, min_drop_n=0.0)  # fmt: skip
    for rate_hz in (1000.0, 100.0):
        count = round(0.3 * rate_hz)
        times = [round(i * 1e9 / rate_hz) for i in range(count + 1)]
        forces = [2.0 - 1.0 * i / rate_hz for i in range(count + 1)]
        events = detect_slips(params, times, forces)
        assert events and events[0].trigger == "cusum"
        assert times.index(events[0].detection_time_ns) == pytest.approx(0.28 * rate_hz, abs=1)


def test_the_warm_up_and_the_train_window_are_counts_at_1khz_and_times_above() -> None:
    warm = DetectorParams(warmup_s=0.016)
    for rate_hz, samples in ((1000.0, 16), (2000.0, 32), (10.0, 16)):
        state = detector_init(warm)
        times = [round(i * 1e9 / rate_hz) + (1000 if i % 2 else 0) for i in range(40)]  # ±1 µs jitter
        for i, t in enumerate(times):
            state, _ = detector_step(warm, state, t, 0.001 * (i % 3))
            assert state.warmed == (i >= samples), f"{rate_hz}/s, increment {i}"
    assert DetectorParams().warmup_s == 0.0  # the default: 16 increments at every rate
    from model.slip_detector import _train_samples

    assert _train_samples(DetectorParams(), 1e-3) == 8 and _train_samples(DetectorParams(), 0.999e-3) == 8
    assert _train_samples(DetectorParams(), 0.5e-3) == 16 and _train_samples(DetectorParams(), 0.1) == 8


def test_the_percentage_drop_forgets_a_short_high_reading_over_a_slow_drift():
    # A two-sample high reading of +0.25 N at a 2.5 N hold, then the hold drifts 0.45 N down over 5 s
    # (a noisy cell's offset drift): 18 % below that reading, but no slip. Only the percentage drop
    # is on (the noise-scaled triggers would see the high reading itself on a noise-free trace).
    _, times, forces = ramp_then(2.5, [(0.5, 2.5), (6.0, 2.05)], noise_n=0.0, seed=0)
    forces[1000] += 0.25  # 0.5 s into the hold
    forces[1001] += 0.25
    before = DetectorParams(drop_leak_n_per_s=0.0, noise_k=None, creep_k=None)
    assert [e.trigger for e in detect_slips(before, times, forces)] == ["drop"]
    assert detect_slips(DetectorParams(noise_k=None, creep_k=None), times, forces) == []
