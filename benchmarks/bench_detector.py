"""Slip detector on synthetic traces: latency, misses, trains, false alarms and peak bias per slip kind.

Run: .venv/bin/python benchmarks/bench_detector.py [--trials 100] [--quiet-samples 10000000]
     [--noisy-samples 2000000] [--jobs 2] [--seed 0] [--before]

Traces are sampled at 1 kHz with Gaussian load-cell noise (default 5 mN, the emulator's). A slip
trace ramps at `--ramp` N/s for 1 s up to the true slip load P (uniform in 2.5-20 N), then:
  * drop X %: the tension falls by X % of P in one sample and stays there;
  * creep X % over D s: the tension sags linearly by X % of P over D s (the winch keeps reeling);
  * train X % xN: a sudden drop of X % of P, then N-1 more of X % of P, 30 ms apart (stick-slip).
Latency = samples from the first sample after the slip onset up to and including the detecting
sample (a sudden drop seen on its 2nd sample has latency 2); a miss is no event within 3 s after the
onset or an event before it. Peak bias = detected peak − P. After the event the latched detector is
stepped over the next 0.2 s (the protocols' `hold_after_slip_s`) with `further_drops`: "trains"
counts the events with at least one further drop (a stick-slip classification); for train cases
"count ok" counts the trials whose further drops are exactly N-1.
False alarms are counted on quiet holds (2.5 N after a 0.5 s ramp, in 60 s segments): plain; with
a 0.2 N peak-to-peak drift (20 s sine); with ±30 σ single-sample spikes (each sample with probability 10⁻⁴) on
top of the drift. The noisy cell (`--noisy-*`) has 10× the noise, an offset drift (the sine plus
0.1 N/min), ±30 σ spikes (probability 10⁻⁴ per sample), 50 Hz mains hum of amplitude 5 σ of the default
cell (25 mN) and a gain creeping by +1 %/min; it is measured on quiet holds and on slips.
Segments run in `--jobs` processes (the step function is pure Python, one core each).
`--before` adds the detector before the noise, creep and train rules
(`noise_k=none creep_k=none train_k=none spike_samples=1`).
`--smoke`: every case, quiet case, cell and detector, on one trial each and one quiet segment of
2,000 samples (instead of 60,000) per quiet case.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from model.slip_detector import DetectorParams, detector_init, detector_step, further_drops

RATE_HZ = 1000.0
DT_NS = 1_000_000
T0_NS = 1_700_000_000_000_000_000
HOLD_S = 0.2  # the protocols' hold_after_slip_s: the window in which further drops are counted
SEGMENT = 60_000  # quiet samples per task
SMOKE_SEGMENT = 2_000  # the same, in smoke mode


@dataclass(frozen=True)
class Cell:
    """The load cell's artefacts (all off but the Gaussian noise by default)."""

    noise_n: float
    drift: bool = False  # 0.2 N peak-to-peak sine over 20 s
    drift_n_per_min: float = 0.0  # offset ramp
    spikes: bool = False  # ±30 σ single-sample spikes, 1 in 10,000 samples on average
    hum_n: float = 0.0  # 50 Hz amplitude
    gain_per_min: float = 0.0  # relative gain change per minute

    def apply(self, rng: np.random.Generator, clean: np.ndarray) -> np.ndarray:
        """The cell's reading of the clean tension `clean` (1 kHz samples)."""
        count = clean.size
        t_s = np.arange(count) / RATE_HZ
        out = clean * (1.0 + self.gain_per_min * t_s / 60.0)
        if self.drift:
            phase = 2.0 * np.pi * rng.uniform()  # continuous at the start: no step
            out = out + 0.1 * (np.sin(2.0 * np.pi * t_s / 20.0 + phase) - np.sin(phase))
        if self.drift_n_per_min:
            out = out + self.drift_n_per_min * t_s / 60.0
        if self.hum_n:
            out = out + self.hum_n * np.sin(2.0 * np.pi * 50.0 * t_s + 2.0 * np.pi * rng.uniform())
        out = out + rng.normal(0.0, self.noise_n, count)
        if self.spikes:  # each sample a spike with probability 1e-4 (short slip traces get some too)
            where = np.flatnonzero(rng.random(count) < 1e-4)
            out[where] += rng.choice([-30.0, 30.0], where.size) * self.noise_n
        return out


def default_cell(noise_n: float) -> Cell:
    return Cell(noise_n)


def noisy_cell(noise_n: float) -> Cell:
    return Cell(
        10.0 * noise_n, drift=True, drift_n_per_min=0.1, spikes=True, hum_n=5.0 * noise_n, gain_per_min=0.01
    )


@dataclass(frozen=True)
class Case:
    kind: str  # drop, creep, train
    size: float  # fraction of the slip load
    duration_s: float = 0.0  # creep: the sag's duration
    drops: int = 1  # train: drops in all

    @property
    def label(self) -> str:
        if self.kind == "creep":
            return f"creep {self.size:.0%} over {self.duration_s:g} s"
        if self.kind == "train":
            return f"train {self.size:.0%} x{self.drops}"
        return f"drop {self.size:.0%}"


def slip_trace(
    rng: np.random.Generator, case: Case, ramp: float, cell: Cell
) -> tuple[np.ndarray, int, float]:
    """(forces, index of the first sample after the onset, true slip load)."""
    load = float(rng.uniform(2.5, 20.0))
    ramp_n = int(RATE_HZ)
    rise = load - ramp * (np.arange(ramp_n, 0, -1) - 1) / RATE_HZ  # ends exactly at the load
    after_n = 3 * int(RATE_HZ)
    k = np.arange(1, after_n + 1)
    if case.kind == "creep":
        after = load * (1.0 - case.size * np.minimum(k / (case.duration_s * RATE_HZ), 1.0))
    else:
        steps = case.drops if case.kind == "train" else 1
        count = np.zeros(after_n)
        for j in range(steps):
            count[k > j * 30] += 1.0  # drop j happens 30 ms after drop j-1
        after = load * (1.0 - case.size * count)
    forces = cell.apply(rng, np.concatenate([rise, after]))
    return forces, ramp_n, load


@dataclass(frozen=True)
class SlipTask:
    params: DetectorParams
    case: Case
    trials: int
    seed: int
    ramp: float
    cell: Cell


@dataclass
class SlipStats:
    latencies: list[int]
    biases_n: list[float]
    relative: list[float]
    onset_errors: list[int]
    kinds: dict[str, int]
    misses: int
    trains: int  # events followed by at least one further drop in the hold
    count_ok: int  # trials whose further drops equal the case's drops - 1


def run_slip_task(task: SlipTask) -> SlipStats:
    rng = np.random.default_rng(task.seed)
    stats = SlipStats([], [], [], [], {}, 0, 0, 0)
    params = task.params
    for _ in range(task.trials):
        forces, first, load = slip_trace(rng, task.case, task.ramp, task.cell)
        times = (T0_NS + np.arange(forces.size, dtype=np.int64) * DT_NS).tolist()
        values = forces.tolist()
        state = detector_init(params)
        event = None
        index = 0
        while index < len(times):
            state, event = detector_step(params, state, times[index], values[index])
            if event is not None:
                break
            index += 1
        if event is None or index < first:
            stats.misses += 1
            continue
        hold_end = index + 1 + int(HOLD_S * RATE_HZ)
        _, drops = further_drops(params, state, times[index + 1 : hold_end], values[index + 1 : hold_end])
        stats.latencies.append(index - first + 1)
        stats.biases_n.append(event.peak_force_n - load)
        stats.relative.append(abs(event.peak_force_n - load) / load)
        stats.onset_errors.append((event.onset_time_ns - times[first - 1]) // DT_NS)
        stats.kinds[event.kind] = stats.kinds.get(event.kind, 0) + 1
        stats.trains += drops > 0
        stats.count_ok += drops == task.case.drops - 1
    return stats


def merge(parts: Sequence[SlipStats]) -> SlipStats:
    out = SlipStats([], [], [], [], {}, 0, 0, 0)
    for p in parts:
        out.latencies += p.latencies
        out.biases_n += p.biases_n
        out.relative += p.relative
        out.onset_errors += p.onset_errors
        for k, v in p.kinds.items():
            out.kinds[k] = out.kinds.get(k, 0) + v
        out.misses += p.misses
        out.trains += p.trains
        out.count_ok += p.count_ok
    return out


def slip_line(stats: SlipStats, case: Case, trials: int) -> str:
    if not stats.latencies:
        return f"misses {stats.misses}/{trials}"
    lat = np.array(stats.latencies)
    bias = np.array(stats.biases_n) * 1e3
    train = f"count ok {stats.count_ok}" if case.kind == "train" else f"trains {stats.trains}"
    return (
        f"latency median {np.median(lat):.0f} p99 {np.percentile(lat, 99):.0f} max {lat.max()} | "
        f"misses {stats.misses}/{trials} | peak bias mean {bias.mean():+.1f} mN "
        f"(|bias| p99 {np.percentile(np.abs(bias), 99):.1f} mN, max {np.abs(bias).max():.1f} mN "
        f"= {max(stats.relative):.2%} of the load) | "
        f"onset error median {np.median(stats.onset_errors):+.0f} samples | kinds {stats.kinds} | {train}"
    )


@dataclass(frozen=True)
class QuietTask:
    params: DetectorParams
    cell: Cell
    seed: int
    segment: int  # its number, for the alarm descriptions
    samples: int  # the hold's (SEGMENT; SMOKE_SEGMENT in smoke mode)


def run_quiet_task(task: QuietTask) -> tuple[list[str], int]:
    """(a description of each false alarm, samples) on one quiet segment: a 0.5 s ramp to 2.5 N, a hold."""
    rng = np.random.default_rng(task.seed)
    clean = np.concatenate([2.5 * np.arange(500) / 500.0, np.full(task.samples, 2.5)])
    forces = task.cell.apply(rng, clean).tolist()
    times = (T0_NS + np.arange(len(forces), dtype=np.int64) * DT_NS).tolist()
    state = detector_init(task.params)
    alarms = []
    for t_ns, force in zip(times, forces, strict=True):
        state, event = detector_step(task.params, state, t_ns, force)
        if event is not None:
            after_ramp_s = (event.detection_time_ns - T0_NS) / 1e9 - 0.5
            alarms.append(
                f"segment {task.segment}: {event.trigger} ({event.kind}) {after_ramp_s:.3f} s after the "
                f"ramp, {(event.peak_force_n - event.force_after_n) * 1e3:.0f} mN below the peak "
                f"{event.peak_force_n:.4f} N"
            )
    return alarms, task.samples


def quiet_line(
    pool: ProcessPoolExecutor,
    params: DetectorParams,
    cell: Cell,
    samples: int,
    seed: int,
    show: bool,
    segment: int = SEGMENT,
) -> str:
    segments = max(1, -(-samples // segment))
    seeds = np.random.SeedSequence(seed).generate_state(segments)
    tasks = [QuietTask(params, cell, int(s), i, segment) for i, s in enumerate(seeds)]
    results = list(pool.map(run_quiet_task, tasks))
    alarms = sum(len(a) for a, _ in results)
    total = sum(n for _, n in results)
    line = f"{alarms} false alarms in {total:,} quiet samples ({alarms / total * 1e6:.2f} per 10^6)"
    details = [d for a, _ in results for d in a] if show else []
    return "\n".join([line, *(f"    {d}" for d in details)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--quiet-samples", type=int, default=10_000_000)
    parser.add_argument("--noisy-samples", type=int, default=2_000_000)
    parser.add_argument("--noise", type=float, default=0.005, help="load-cell noise sigma [N]")
    parser.add_argument("--ramp", type=float, default=5.0, help="ramp rate before the slip [N/s]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--before", action="store_true", help="also the detector before the new rules")
    parser.add_argument("--skip-quiet", action="store_true")
    parser.add_argument("--skip-slips", action="store_true")
    parser.add_argument(
        "--quiet-cases",
        nargs="*",
        default=["quiet", "drift", "drift+spikes", "noisy cell"],
        help="which quiet cases to measure",
    )
    parser.add_argument("--show-alarms", action="store_true", help="describe every false alarm")
    parser.add_argument("--detector", nargs="*", default=[], help="key=value overrides of the defaults")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:  # every case and quiet case, both detectors, on a few trials and samples
        args.trials, args.quiet_samples, args.noisy_samples = 1, SMOKE_SEGMENT, SMOKE_SEGMENT
        args.jobs, args.before = 1, True
    detectors = {"defaults": DetectorParams(arm_threshold_n=1.0).with_overrides(args.detector)}
    if args.before:
        detectors["before (drop rule on single samples)"] = DetectorParams(
            arm_threshold_n=1.0, noise_k=None, creep_k=None, train_k=None, spike_samples=1
        )
    cases = [Case("drop", s) for s in (0.03, 0.05, 0.10, 0.15, 0.20)]
    cases += [Case("creep", 0.10, d) for d in (0.05, 0.5, 2.0)] + [Case("creep", 0.03, 2.0)]
    cases += [Case("train", 0.05, drops=3), Case("train", 0.10, drops=2)]
    cells = {"default cell": default_cell(args.noise), "noisy cell": noisy_cell(args.noise)}
    print(
        f"noise {args.noise * 1e3:g} mN, ramp {args.ramp:g} N/s, {args.trials} trials/case, "
        f"seed {args.seed}, {args.jobs} processes"
    )
    with ProcessPoolExecutor(args.jobs) as pool:
        for name, params in detectors.items():
            for cell_name, cell in cells.items():
                print(f"\n== {name}, {cell_name}")
                for i, case in [] if args.skip_slips else list(enumerate(cases)):
                    start = time.perf_counter()
                    shares = [
                        args.trials // args.jobs + (j < args.trials % args.jobs) for j in range(args.jobs)
                    ]
                    seeds = np.random.SeedSequence([args.seed, i]).generate_state(args.jobs)
                    tasks = [
                        SlipTask(params, case, n, int(s), args.ramp, cell)
                        for n, s in zip(shares, seeds, strict=True)
                        if n
                    ]
                    stats = merge(list(pool.map(run_slip_task, tasks)))
                    line = slip_line(stats, case, args.trials)
                    print(f"{case.label:22s} {line}  [{time.perf_counter() - start:.1f} s]", flush=True)
                if args.skip_quiet:
                    continue
                if cell_name == "default cell":
                    quiet = [("quiet", cell), ("drift", Cell(args.noise, drift=True))]
                    quiet.append(("drift+spikes", Cell(args.noise, drift=True, spikes=True)))
                    samples = args.quiet_samples
                else:
                    quiet, samples = [("noisy cell", cell)], args.noisy_samples
                for label, quiet_cell in quiet:
                    if label not in args.quiet_cases:
                        continue
                    start = time.perf_counter()
                    segment = SMOKE_SEGMENT if args.smoke else SEGMENT
                    line = quiet_line(
                        pool, params, quiet_cell, samples, args.seed + 1, args.show_alarms, segment
                    )
                    print(f"{label:22s} {line}  [{time.perf_counter() - start:.1f} s]", flush=True)


if __name__ == "__main__":
    main()
