"""Slip detector on synthetic traces: latency, misses, false alarms and peak bias per slip kind and size.

Run: .venv/bin/python benchmarks/bench_detector.py [--trials 100] [--quiet-samples 1000000] [--seed 0]

Traces are sampled at 1 kHz with Gaussian load-cell noise (default 5 mN, the emulator's). A slip
trace ramps at `--ramp` N/s for 1 s up to the true slip load P (uniform in 2.5-20 N), then:
  * drop X %: the tension falls by X % of P in one sample and stays there;
  * creep X % over D s: the tension sags linearly by X % of P over D s (the winch keeps reeling).
Latency = samples from the first sample after the slip onset up to and including the detecting
sample (a sudden drop seen on its 2nd sample has latency 2); a miss is no event within 3 s after the
onset or an event before it. Peak bias = detected peak − P. False alarms are counted on quiet holds
(2.5 N after a 0.5 s ramp, in 60 s segments): plain, with a 0.2 N peak-to-peak drift (20 s sine),
and with one ±30 σ single-sample spike per 10,000 samples on top of the drift.
Each row is printed for the current defaults and for the detector before the noise and creep
triggers (`noise_k=none creep_k=none spike_samples=1`).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from model.slip_detector import DetectorParams, SlipEvent, detect_slips

RATE_HZ = 1000.0
DT_NS = 1_000_000
T0_NS = 1_700_000_000_000_000_000


def slip_trace(
    rng: np.random.Generator, kind: str, size: float, duration_s: float, ramp: float, noise: float
) -> tuple[list[int], list[float], int, float]:
    """(times, forces, index of the first sample after the onset, true slip load)."""
    load = float(rng.uniform(2.5, 20.0))
    ramp_n = int(RATE_HZ)
    rise = load - ramp * (np.arange(ramp_n, 0, -1) - 1) / RATE_HZ  # ends exactly at the load
    after_n = 3 * int(RATE_HZ)
    k = np.arange(1, after_n + 1)
    if kind == "drop":
        after = np.full(after_n, load * (1.0 - size))
    else:
        sag = np.minimum(k / (duration_s * RATE_HZ), 1.0)
        after = load * (1.0 - size * sag)
    clean = np.concatenate([rise, after])
    forces = clean + rng.normal(0.0, noise, clean.size)
    times = [T0_NS + i * DT_NS for i in range(clean.size)]
    return times, [float(f) for f in forces], ramp_n, load


def quiet_trace(rng: np.random.Generator, count: int, noise: float, drift: bool, spikes: bool) -> list[float]:
    t_s = np.arange(count) / RATE_HZ
    hold = np.full(count, 2.5)
    if drift:
        phase = 2.0 * np.pi * rng.uniform()  # continuous at the end of the ramp: no step
        hold = hold + 0.1 * (np.sin(2.0 * np.pi * t_s / 20.0 + phase) - np.sin(phase))
    if spikes:
        where = rng.integers(0, count, count // 10_000)
        hold[where] += rng.choice([-30.0, 30.0], where.size) * noise
    ramp = 2.5 * np.arange(500) / 500.0
    return [float(f) for f in np.concatenate([ramp, hold]) + rng.normal(0.0, noise, count + 500)]


def run_slips(
    params: DetectorParams, args: argparse.Namespace, kind: str, size: float, duration_s: float
) -> str:
    rng = np.random.default_rng(args.seed)
    latencies: list[int] = []
    biases: list[float] = []
    relative: list[float] = []
    onset_errors: list[int] = []
    kinds: dict[str, int] = {}
    misses = 0
    for _ in range(args.trials):
        times, forces, first, load = slip_trace(rng, kind, size, duration_s, args.ramp, args.noise)
        events: list[SlipEvent] = detect_slips(params, times, forces)
        event = events[0] if events else None
        if event is None or event.detection_time_ns < times[first] or event.detection_time_ns > times[-1]:
            misses += 1
            continue
        latencies.append((event.detection_time_ns - times[first]) // DT_NS + 1)
        biases.append(event.peak_force_n - load)
        relative.append(abs(event.peak_force_n - load) / load)
        onset_errors.append((event.onset_time_ns - times[first - 1]) // DT_NS)
        kinds[event.kind] = kinds.get(event.kind, 0) + 1
    if not latencies:
        return f"misses {misses}/{args.trials}"
    lat = np.array(latencies)
    bias = np.array(biases) * 1e3
    return (
        f"latency median {np.median(lat):.0f} p99 {np.percentile(lat, 99):.0f} max {lat.max()} | "
        f"misses {misses}/{args.trials} | peak bias mean {bias.mean():+.1f} mN "
        f"(|bias| p99 {np.percentile(np.abs(bias), 99):.1f} mN, max {np.abs(bias).max():.1f} mN "
        f"= {max(relative):.2%} of the load) | "
        f"onset error median {np.median(onset_errors):+.0f} samples | kinds {kinds}"
    )


def run_quiet(params: DetectorParams, args: argparse.Namespace, drift: bool, spikes: bool) -> str:
    rng = np.random.default_rng(args.seed + 1)
    segment = 60_000
    alarms = 0
    samples = 0
    while samples < args.quiet_samples:
        forces = quiet_trace(rng, segment, args.noise, drift, spikes)
        times = [T0_NS + i * DT_NS for i in range(len(forces))]
        alarms += len(detect_slips(params, times, forces))
        samples += segment
    return f"{alarms} false alarms in {samples:,} quiet samples ({alarms / samples * 1e6:.1f} per 10^6)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--quiet-samples", type=int, default=1_000_000)
    parser.add_argument("--noise", type=float, default=0.005, help="load-cell noise sigma [N]")
    parser.add_argument("--ramp", type=float, default=5.0, help="ramp rate before the slip [N/s]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--skip-quiet", action="store_true")
    parser.add_argument("--skip-slips", action="store_true")
    parser.add_argument("--detector", nargs="*", default=[], help="key=value overrides of the defaults")
    args = parser.parse_args()
    detectors = {
        "defaults": DetectorParams(arm_threshold_n=1.0).with_overrides(args.detector),
        "before (drop rule on single samples)": DetectorParams(
            arm_threshold_n=1.0, noise_k=None, creep_k=None, spike_samples=1
        ),
    }
    cases = [("drop", s, 0.0) for s in (0.03, 0.05, 0.10, 0.15, 0.20)]
    cases += [("creep", 0.10, d) for d in (0.05, 0.5, 2.0)] + [("creep", 0.03, 2.0)]
    print(
        f"noise {args.noise * 1e3:g} mN, ramp {args.ramp:g} N/s, {args.trials} trials/case, seed {args.seed}"
    )
    for name, params in detectors.items():
        print(f"\n== {name}")
        for kind, size, duration in [] if args.skip_slips else cases:
            label = f"{kind} {size:.0%}" + (f" over {duration:g} s" if kind == "creep" else "")
            start = time.perf_counter()
            line = run_slips(params, args, kind, size, duration)
            print(f"{label:22s} {line}  [{time.perf_counter() - start:.1f} s]")
        if not args.skip_quiet:
            for label, drift, spikes in (
                ("quiet", False, False),
                ("drift", True, False),
                ("drift+spikes", True, True),
            ):
                print(f"{label:22s} {run_quiet(params, args, drift, spikes)}")


if __name__ == "__main__":
    main()
