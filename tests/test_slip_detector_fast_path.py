"""`detector_run` (with its quiet-stretch fast path) steps exactly as `detector_step` sample by sample."""

from __future__ import annotations

import dataclasses
import math
import random
from collections.abc import Callable

import pytest

from model.slip_detector import (
    QUIET_STRETCH_FIELDS,
    DetectorParams,
    DetectorState,
    SlipEvent,
    detector_init,
    detector_run,
    detector_step,
)


def _recording(seed: int) -> tuple[list[int], list[float]]:
    """Ramps with noise, sudden and small drops, creep, stick-slip trains, spikes and holds at 1 kHz."""
    rng = random.Random(seed)
    times: list[int] = []
    forces: list[float] = []
    t = 1_000_000_000
    noise = rng.choice([0.002, 0.005, 0.05])
    for _ in range(6):
        level = rng.uniform(-0.05, 0.3)
        peak = rng.uniform(3.0, 40.0)
        rate = rng.uniform(0.002, 0.05)  # N per sample
        ramp = []
        while level < peak:
            level += rate
            ramp.append(level)
        kind = rng.choice(["sudden", "small", "creep", "train", "none"])
        after: list[float] = []
        if kind == "sudden":
            after = [peak * (1 - 0.3 * min(1.0, k / 5)) for k in range(300)]
        elif kind == "small":
            after = [peak * (1 - 0.04 * min(1.0, k / 3)) for k in range(300)]
        elif kind == "creep":
            after = [peak * (1 - 0.1 * min(1.0, k / 800)) for k in range(1200)]
        elif kind == "train":
            value = peak
            for _drop in range(4):
                value *= 0.93
                after += [value] * 40
                after += [value + rate * k for k in range(60)]
                value = after[-1]
        else:
            after = [peak] * 400
        after += [max(0.0, after[-1] if after else peak) * (1 - k / 200) for k in range(200)] + [0.0] * 300
        for value in [0.0] * 200 + ramp + after:
            f = value + rng.gauss(0.0, noise)
            if rng.random() < 0.002:
                f += rng.choice([-1.0, 1.0]) * rng.uniform(0.05, 2.0)  # a spike
            times.append(t)
            forces.append(f)
            t += 1_000_000 if rng.random() > 0.01 else rng.choice([0, 3_000_000])  # repeats, gaps
    return times, forces


def _plain(
    params: DetectorParams, times: list[int], forces: list[float]
) -> list[tuple[int, DetectorState, SlipEvent]]:
    out = []
    state = detector_init(params)
    for i, (t, f) in enumerate(zip(times, forces, strict=True)):
        state, event = detector_step(params, state, t, f)
        if event is not None:
            out.append((i, state, event))
            if i % 3 == 0:
                state = detector_init(params)  # as the runner does when the winch does not confirm
    out.append((len(times), state, None))  # type: ignore[arg-type]
    return out


def _fast(
    params: DetectorParams, times: list[int], forces: list[float], cuts: list[int]
) -> tuple[list[tuple[int, DetectorState, SlipEvent]], dict[int, DetectorState]]:
    out = []
    at_cuts: dict[int, DetectorState] = {}
    state = detector_init(params)
    i = 0
    bounds = sorted({*cuts, len(times)})
    for end in bounds:
        while i < end:
            state, k, event = detector_run(params, state, times[:end], forces[:end], i)
            if event is None:
                i = end
                break
            out.append((k, state, event))
            if k % 3 == 0:
                state = detector_init(params)
            i = k + 1
        at_cuts[end] = state
    out.append((len(times), state, None))  # type: ignore[arg-type]
    return out, at_cuts


PARAMS = [
    DetectorParams(),
    DetectorParams(arm_threshold_n=2.0, drop_fraction=0.15),
    DetectorParams(spike_samples=1.0, noise_k=None, train_k=None, drop_leak_n_per_s=0.0),
    DetectorParams(cusum_threshold_n=0.5, creep_k=None, min_drop_n=0.1),
    DetectorParams(drop_fraction=None, noise_k=6.0, creep_k=4.0, noise_floor_n=0.0001),
    DetectorParams(slope_n_per_s=50.0),  # the slope window: every sample by the plain step
]


@pytest.mark.parametrize("params", PARAMS, ids=range(len(PARAMS)))
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_detector_run_equals_detector_step(params: DetectorParams, seed: int) -> None:
    times, forces = _recording(seed)
    expected = _plain(params, times, forces)
    assert len(expected) > 3  # the recordings fire
    cuts = sorted(random.Random(seed).sample(range(1, len(times)), 40))
    got, at_cuts = _fast(params, times, forces, cuts)
    assert got == expected
    # The state at any boundary is the plain state there (only checked where no event reset it).
    plain_state = detector_init(params)
    for i, (t, f) in enumerate(zip(times, forces, strict=True)):
        plain_state, event = detector_step(params, plain_state, t, f)
        if event is not None and i % 3 == 0:
            plain_state = detector_init(params)
        if i + 1 in at_cuts:
            assert at_cuts[i + 1] == plain_state


def test_detector_run_rejects_what_detector_step_rejects() -> None:
    params = DetectorParams()
    times = [k * 1_000_000 for k in range(100)]
    forces = [0.01 * k for k in range(100)]
    state, k, event = detector_run(params, detector_init(params), times, forces)
    assert k == 100 and event is None
    for bad_times, bad_forces, message in (
        ([*times, 10], [*forces, 1.0], "earlier than the previous sample"),
        ([*times, times[-1] + 1], [*forces, math.nan], "allowed: finite"),
        ([*times, times[-1] + 1], [*forces, math.inf], "allowed: finite"),
    ):
        with pytest.raises(ValueError, match=message):
            detector_run(params, state, bad_times, bad_forces, 100)
    with pytest.raises(ValueError, match="one force per time"):
        detector_run(params, state, times, forces[:-1])


def test_the_fast_path_takes_the_quiet_stretches(monkeypatch: pytest.MonkeyPatch) -> None:
    """Most samples of a ramp never reach the plain step (else the test above would prove little)."""
    import model.slip_detector as module

    calls = []

    def counting_step(*args: object) -> object:
        calls.append(1)
        return detector_step(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(module, "detector_step", counting_step)
    params = PARAMS[1]
    times, forces = _recording(0)
    got, _ = _fast(params, times, forces, [])
    assert got == _plain(params, times, forces)
    assert 0 < len(calls) < 0.2 * len(times)


def test_the_fast_path_knows_every_detector_field() -> None:
    """A new `DetectorParams` field fails here until `QUIET_STRETCH_FIELDS` says how the fast path uses it."""
    names = [f.name for f in dataclasses.fields(DetectorParams)]
    assert sorted(QUIET_STRETCH_FIELDS) == sorted(names)
    assert sorted(SAMPLERS) == sorted(names)  # and the randomised test below draws it


def _maybe(rng: random.Random, low: float, high: float, none_share: float = 0.3) -> float | None:
    return None if rng.random() < none_share else rng.uniform(low, high)


# One sampler per field, over values a protocol might use (each field varies in the test below).
SAMPLERS: dict[str, Callable[[random.Random], float | None]] = {
    "arm_threshold_n": lambda r: r.uniform(0.2, 5.0),
    "drop_fraction": lambda r: _maybe(r, 0.02, 0.4),
    "min_drop_n": lambda r: r.uniform(0.0, 1.0),
    "slope_n_per_s": lambda r: _maybe(r, 5.0, 200.0, none_share=0.85),
    "slope_window_s": lambda r: r.uniform(0.005, 0.05),
    "cusum_threshold_n": lambda r: _maybe(r, 0.1, 2.0, none_share=0.5),
    "cusum_drift_n_per_s": lambda r: r.uniform(0.0, 200.0),
    "rearm_below_n": lambda r: _maybe(r, 0.1, 3.0, none_share=0.5),
    "noise_k": lambda r: _maybe(r, 3.0, 20.0),
    "noise_floor_n": lambda r: r.uniform(0.0001, 0.05),
    "noise_window_s": lambda r: r.uniform(0.05, 2.0),
    "trend_window_s": lambda r: r.uniform(0.02, 1.0),
    "peak_leak_n_per_s": lambda r: r.uniform(0.0, 5.0),
    "creep_k": lambda r: _maybe(r, 3.0, 20.0),
    "creep_drift_n_per_s": lambda r: r.uniform(0.0, 1.0),
    "creep_min_s": lambda r: r.uniform(0.0, 0.3),
    "spike_samples": lambda r: r.choice([1.0, 2.0]),
    "train_k": lambda r: _maybe(r, 3.0, 20.0),
    "drop_leak_n_per_s": lambda r: r.uniform(0.0, 5.0),
    "drop_ramp_s": lambda r: _maybe(r, 0.0, 0.3, none_share=0.5),
    "warmup_s": lambda r: r.uniform(0.0, 0.05),
    "train_window_s": lambda r: r.uniform(0.0, 0.03),
}


def _random_params(rng: random.Random) -> DetectorParams:
    while True:
        values = {name: draw(rng) for name, draw in SAMPLERS.items()}
        try:
            return DetectorParams(**values)  # type: ignore[arg-type]
        except ValueError:  # no trigger on: draw again
            continue


@pytest.mark.parametrize("seed", range(24))
def test_detector_run_equals_detector_step_for_random_parameters(seed: int) -> None:
    """The fast path steps as the plain step over parameter sets drawn across every field."""
    rng = random.Random(1000 + seed)
    params = _random_params(rng)
    times, forces = _recording(seed % 4)
    cut = len(times) // 3  # a third of a recording: six ramps would cost seconds per set
    times, forces = times[:cut], forces[:cut]
    expected = _plain(params, times, forces)
    cuts = sorted(rng.sample(range(1, len(times)), 10))
    got, _ = _fast(params, times, forces, cuts)
    assert got == expected
