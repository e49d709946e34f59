"""The default protocol at the load-cell rates labs own (issue 21): outcomes, k, lag, slip-load error.

Run (from the repository root, with the project's environment):

    python benchmarks/bench_rates.py runs [--rates 10 80 320 1000] [--seeds 0 1 2] [--trials]
                                          [--scenario noisy-cell]
    python benchmarks/bench_rates.py quiet [--rates 10 80 320 1000] [--samples 1000000]

`runs`: `rig run protocols/joint_estimation.yaml --seed S --json` on the built-in simulated rig with
only `simulation.loadcell_rate_hz` changed. Per run: the outcomes of the 24 trials, k with its 99 %
bounds against the true k, and the run's simulated time (first trial start to last trial end). From
the log, per trial, against `sim_truth`'s first slip: the detection lag in samples (n: the detecting
sample is the n-th taken after the true onset, its sampling time recovered from its device time),
and the slip-load error, detected peak / true slip load − 1 (sampling and noise together).
`--scenario NAME` runs a config of protocols/rigs/scenarios/ at each rate instead (the early
column counts detections before the first true slip or in a trial without one: false alarms).
`--trials` adds, after each run's row, every trial detected more than 2 samples after the onset:
its lag, error, trigger, true slips, and the forces of the 4 samples before and after the onset.

`quiet`: the protocol's detector, with the defaults for each rate (`params_for_rate`), over quiet
samples of the emulated load cell at that rate and the default noise (5 mN): 10⁴-sample segments,
each tared on 10 samples at zero load, then a ramp at the rate-aware ramp's speed for 2.5 N
(`rig.runner.ramp_speed`) up to a 2.5 N hold. Every detection is a false alarm; the detector restarts
after each.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from bench_detector_sim import detections_with_sample_times  # benchmarks/ is the script's directory
from smoke_mode import SMOKE_HELP, short_protocol

from model.slip_detector import detector_init, detector_run, params_for_rate
from rig.analysis.runlog import read_parts, run_settings
from rig.cli import main as rig_main
from rig.hw.loadcell.formats import LineDecoder
from rig.inputs.protocol import load_protocol
from rig.log.format import schemas
from rig.runner.ramp_speed import RampSpeeds
from rig.sim.loadcell.emulator import LoadCellEmulator, SignalModel
from rig.sim.physics.link_presets import make_preset

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL = ROOT / "protocols" / "joint_estimation.yaml"


def run_at(
    rate_hz: float, seed: int, folder: Path, scenario: str | None = None, protocol: Path = PROTOCOL
) -> tuple[int, dict[str, Any]]:
    """`rig run` of the default protocol with the simulated cell at `rate_hz`; (exit code, report).

    `scenario`: a config of protocols/rigs/scenarios/ (by name) instead of the built-in simulated rig.
    """
    config: dict[str, Any] = {"extends": "simulated"}
    if scenario is not None:
        config = yaml.safe_load((ROOT / "protocols" / "rigs" / "scenarios" / f"{scenario}.yaml").read_text())
    config["name"] = f"rate{rate_hz:g}"
    config.setdefault("simulation", {})["loadcell_rate_hz"] = rate_hz
    rig = folder / "rig.yaml"
    rig.write_text(yaml.safe_dump(config))
    argv = ["run", str(protocol), "--rig", str(rig), "--seed", str(seed), "--json", "--out", str(folder)]
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = rig_main(argv)
    return code, json.loads(out.getvalue())


def score(
    report: dict[str, Any], rate_hz: float, late: list[str] | None = None
) -> tuple[list[int], list[float], int]:
    """(detection lags [samples], slip-load errors [relative], early detections) of a run's trials.

    `late`: if given, a line is appended per trial detected more than 2 samples after the onset.
    """
    parts = read_parts(report["log"])
    settings = run_settings(parts, [])
    assert settings.truth is not None, "the log has no sim_truth"
    world = settings.truth["world"]
    offset = world["run_clock_offset_ns"]
    period_ns = 1e9 / rate_hz
    events = detections_with_sample_times(parts, offset)  # (event, true time of its sample)
    trials = world["trials"]
    starts = [t["start_ns"] + offset for t in trials] + [math.inf]
    lags: list[int] = []
    errors: list[float] = []
    early = 0
    for number, (trial, start, end) in enumerate(zip(trials, starts, starts[1:], strict=False), 1):
        mine = [(e, sampled) for e, sampled in events if start <= e.detection_time_ns < end]
        if not mine:
            continue
        if not trial["slip_events"]:
            early += 1  # a detection where nothing slipped
            continue
        event, sampled_ns = mine[0]
        first = trial["slip_events"][0]
        if sampled_ns <= first["onset_time_ns"]:
            early += 1
            continue
        lags.append(math.ceil((sampled_ns - first["onset_time_ns"]) / period_ns))
        errors.append(event.peak_force_n / first["load_n"] - 1.0)
        if late is not None and lags[-1] > 2:
            late.append(
                f"  trial {number}: lag {lags[-1]}, error {errors[-1] * 100:+.3f} %, "
                f"trigger {event.trigger}, {len(trial['slip_events'])} true slips, "
                f"slip load {first['load_n']:.3f} N; forces around the onset: "
                f"{_around(parts, offset, first['onset_time_ns'])}"
            )
    return lags, errors, early


def _around(parts: list[Any], offset_ns: int, onset_ns: int) -> str:
    """The logged forces of the 4 samples before and the 4 after a true time ('|' marks it)."""
    for part in parts:
        cell = part.log.topic(schemas.LOADCELL)
        sampled = cell["device_time_us"].to_numpy() * 1000 + offset_ns
        i = int(np.searchsorted(sampled, onset_ns))
        if 0 < i < len(sampled):
            forces = cell["force_n"].to_numpy()
            before = " ".join(f"{f:.3f}" for f in forces[max(0, i - 4) : i])
            return before + " | " + " ".join(f"{f:.3f}" for f in forces[i : i + 4])
    return "-"


def runs(
    rates: list[float],
    seeds: list[int],
    show_trials: bool = False,
    scenario: str | None = None,
    protocol: Path = PROTOCOL,
) -> None:
    print(
        "| rate [/s] | seed | exit | outcomes | k [99 % bounds] | true k | inside | lag <= 2 "
        "| lag max [samples] | slip-load error mean, max abs [%] | error < 0.5 % | early | run time [s] |"
    )
    print("|" + "---|" * 13)
    for rate in rates:
        for seed in seeds:
            with tempfile.TemporaryDirectory() as folder:
                code, report = run_at(rate, seed, Path(folder), scenario, protocol)
                late: list[str] | None = [] if show_trials else None
                lags, errors, early = score(report, rate, late)
            estimate = report.get("estimate") or {}
            ci = estimate.get("k_ci")
            k_true = report["truth"]["k"]
            inside = ci is not None and ci[0] <= k_true <= ci[1]
            outcomes = Counter(str(t["outcome"]) for t in report["trials"])
            trials = report["trials"]
            span_s = (trials[-1]["end_time_ns"] - trials[0]["start_time_ns"]) / 1e9 if trials else 0.0
            k_text = f"{estimate['k']:.5f} [{ci[0]:.5f}, {ci[1]:.5f}]" if ci else "none"
            err = np.array(errors) * 100
            err_text = f"{err.mean():+.3f}, {np.abs(err).max():.3f}" if err.size else "-"
            print(
                f"| {rate:g} | {seed} | {code} | {', '.join(f'{k} {v}' for k, v in sorted(outcomes.items()))} "  # noqa: E501
                f"| {k_text} | {k_true:.5f} | {'yes' if inside else 'NO'} "
                f"| {sum(n <= 2 for n in lags)}/{len(lags)} "
                f"| {max(lags) if lags else '-'} | {err_text} | {int(np.sum(np.abs(err) < 0.5))}/{err.size} "
                f"| {early} | {span_s:.1f} |",
                flush=True,
            )
            for line in late or []:
                print(line, flush=True)


def quiet_alarms(rate_hz: float, samples: int, seed: int, path: Path = PROTOCOL) -> tuple[int, int]:
    """(false alarms, samples fed) on quiet segments of the emulated cell at `rate_hz`."""
    protocol = load_protocol(path)
    params = params_for_rate(protocol.detector, protocol.detector_given, rate_hz)
    speeds = RampSpeeds(
        fast_rad_s=1.0, slow_rad_s=protocol.ramp.slow_speed_rad_s, rate_hz=rate_hz, n_per_rad=50.0
    )
    ramp_n_per_s = speeds.slow_at(2.5, params.arm_threshold_n) * speeds.n_per_rad
    segment, tare, hold_n = 10_000, 10, 2.5
    period_ns = round(1e9 / rate_hz)

    def tension(t_ns: int) -> float:
        within_s = (t_ns % (segment * period_ns)) * 1e-9 - tare / rate_hz
        return 0.0 if within_s <= 0 else min(hold_n, ramp_n_per_s * within_s)

    preset = make_preset("link1", seed)
    gain = SignalModel().gain_counts_per_n
    signal = SignalModel(noise_counts=preset.loadcell_noise_n * gain)
    emulator = LoadCellEmulator(tension, rate_hz=rate_hz, signal=signal, seed=seed)
    decoder = LineDecoder(emulator.codec)
    alarms = fed = 0
    for index in range(max(1, samples // segment)):
        end_ns = ((index + 1) * segment - 1) * period_ns
        lines = decoder.feed(b"".join(chunk for _, chunk in emulator.lines_until(end_ns)))
        forces = (np.array([ln.raw for ln in lines], dtype=float) - signal.offset_counts) / gain
        forces -= forces[:tare].mean()
        times = [(index * segment + i) * period_ns for i in range(len(forces))]
        values = [float(f) for f in forces]
        state = detector_init(params)
        i = tare
        while i < len(values):
            state, k, fired = detector_run(params, state, times, values, i)
            fed += min(k + 1, len(values)) - i
            if fired is None:
                break
            alarms += 1
            state = detector_init(params)
            i = k + 1
    return alarms, fed


def quiet(rates: list[float], samples: int, seed: int, protocol: Path = PROTOCOL) -> None:
    print("| rate [/s] | quiet samples | false alarms |")
    print("|---|---|---|")
    for rate in rates:
        alarms, fed = quiet_alarms(rate, samples, seed, protocol)
        print(f"| {rate:g} | {fed} | {alarms} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("mode", nargs="?", choices=["runs", "quiet"], help="required but with --smoke")
    parser.add_argument("--rates", type=float, nargs="+", default=[10.0, 80.0, 320.0, 1000.0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--samples", type=int, default=1_000_000, help="quiet: samples per rate")
    parser.add_argument("--seed", type=int, default=0, help="quiet")
    parser.add_argument(
        "--scenario", help="runs: a protocols/rigs/scenarios/ config (e.g. noisy-cell) at each rate"
    )
    parser.add_argument(
        "--trials", action="store_true", help="runs: the trials detected late, with their forces"
    )
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP + "; both modes")
    args = parser.parse_args()
    if (
        args.smoke
    ):  # both modes at 80/s, a two-trial copy of the protocol (an estimate) on a scenario's config
        with tempfile.TemporaryDirectory() as folder:
            protocol = short_protocol(Path(folder))
            runs([80.0], [0], True, "noisy-cell", protocol)
            quiet([80.0], 10_000, args.seed, protocol)  # one segment
        return
    if args.mode is None:
        parser.error("a mode (runs or quiet) is required")
    if args.mode == "runs":
        runs(args.rates, args.seeds, args.trials, args.scenario)
    else:
        quiet(args.rates, args.samples, args.seed)


if __name__ == "__main__":
    main()
