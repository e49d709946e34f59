"""The slip detector on the simulator's own slips, scored against the simulator's truth (`sim_truth`).

Run (from the repository root, with the project's environment):

    python benchmarks/bench_detector_sim.py scenarios [--seeds 0 1 2] [--scenarios default mixed ...]
    python benchmarks/bench_detector_sim.py quiet [--samples 1000000] [--seed 0]
    python benchmarks/bench_detector_sim.py [ratios] [--ratios 0.8 0.9 0.95] [--seed 0]

`scenarios` runs `rig run protocols/joint_estimation.yaml --rig protocols/rigs/scenarios/NAME.yaml`
(`default`: the built-in rig) for each seed, reads the run's log back, and scores the runner's
`/rig/slip` events against the true slip events of `sim_truth`, per slip kind and size: latency in
samples (n: the detection came on the n-th load-cell sample taken after the true onset; the sample's
true sampling time is recovered from its device time, since the host stamps samples about 1 ms late),
misses (a trial that slipped but was not detected), early detections (before the true onset: false
alarms), and the bias of the detected peak against the true slip load. It also prints, per run, the
exit code, the trials done, whether the true k lies within the 99 % bounds, and whether `rig replay`
of the log re-detects the same events (trials matched / trials). The detector is the protocol's
(`model.slip_detector`, as it is).

`quiet` feeds the detector quiet stretches of the emulated load cell, without any slip, at the
default noise and with the noisy-cell scenario's artefacts (protocols/rigs/scenarios/noisy-cell.yaml):
10 s segments, each tared on 0.1 s at zero load, then a 4 N/s ramp (the protocol's slow winch speed)
to a 2.5 N hold. Every detection is a false alarm; the detector restarts after each.

`ratios` is the earlier study: the default run with the simulator's kinetic ratio patched.
A slip drops the tension to `kinetic_ratio` x the peak (preset: 0.8, a 20 % drop). For each ratio the
run is made with the current detector defaults and with the detector before the noise, creep and
train rules (`noise_k: null, creep_k: null, spike_samples: 1, train_k: null, drop_leak_n_per_s: 0`
added to the protocol's detector section).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import math
import tempfile
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from smoke_mode import SMOKE_HELP, short_protocol  # benchmarks/ is the script's directory

import rig.sim.simulated_rig as simulated_rig
from model.slip_detector import DetectorParams, SlipEvent, detector_init, detector_step
from rig.analysis.runlog import read_parts, run_settings
from rig.cli import main as rig_main
from rig.hw.loadcell.formats import LineDecoder
from rig.inputs.protocol import load_protocol
from rig.inputs.rig_config import load_rig_config
from rig.log.format import schemas
from rig.log.reading.frames import frame_payloads
from rig.records import SlipMessage
from rig.sim.loadcell.artefacts import ArtefactModel
from rig.sim.loadcell.emulator import LoadCellEmulator, SignalModel
from rig.sim.physics.link_presets import STREAM_LOADCELL_ARTEFACTS, make_preset, stream_rng
from rig.sim.settings import LoadCellArtefacts, require_simulated

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL = ROOT / "protocols" / "joint_estimation.yaml"
SCENARIOS = ROOT / "protocols" / "rigs" / "scenarios"
SCENARIO_NAMES = (
    "default",
    "small-drops",
    "creep",
    "stick-slip",
    "noisy-cell",
    "additive-scatter",
    "mixed-scatter",
    "mixed",
)
BEFORE = "  noise_k: null\n  creep_k: null\n  spike_samples: 1\n  train_k: null\n  drop_leak_n_per_s: 0\n"
RATE_HZ = 1000.0
SAMPLE_NS = round(1e9 / RATE_HZ)


# ----------------------------------------------------------------------------------- scenarios


@dataclasses.dataclass
class Score:
    """Detections of one slip kind and size."""

    trials: int = 0
    latencies: list[int] = dataclasses.field(default_factory=list)
    biases_n: list[float] = dataclasses.field(default_factory=list)
    relative_biases: list[float] = dataclasses.field(default_factory=list)
    misses: int = 0
    early: int = 0

    def row(self, label: str) -> str:
        lat = np.array(self.latencies)
        if len(lat):
            latency = f"{np.median(lat):.0f} | {np.percentile(lat, 99):.0f} | {lat.max()}"
        else:
            latency = "- | - | -"
        bias = np.array(self.biases_n)
        rel = np.array(self.relative_biases)
        if len(bias):
            worst_n, worst = np.abs(bias).max(), np.abs(rel).max()
            bias_text = f"{bias.mean() * 1e3:+.1f} | {worst_n * 1e3:.1f} | {worst * 100:.2f}"
        else:
            bias_text = "- | - | -"
        counts = f"{self.trials} | {len(lat)} | {latency} | {self.misses} | {self.early}"
        return f"| {label} | {counts} | {bias_text} |"


def size_label(trial: dict[str, Any]) -> str:
    """The slip kind and a size bin of one truth trial."""
    plan = trial["slip"]
    kind = plan["kind"]
    if kind == "sudden":
        return "sudden (20 %)"
    if kind in ("small_drop", "stick_slip", "other_joint"):
        drop = plan["drop_fraction"]
        edges = ((0.05, "< 5 %"), (0.10, "5-10 %"), (1.0, ">= 10 %"))
        return f"{kind} ({next(text for edge, text in edges if drop < edge)})"
    if kind == "creep":
        duration = plan["creep_duration_s"]
        return f"creep ({'< 0.5 s' if duration < 0.5 else '0.5-2 s'})"
    return kind


def run_scenario(name: str, seed: int, folder: Path, protocol: Path = PROTOCOL) -> tuple[int, dict[str, Any]]:
    """`rig run` of the joint-estimation protocol on a scenario; (exit code, JSON report)."""
    argv = ["run", str(protocol), "--seed", str(seed), "--json", "--out", str(folder)]
    if name != "default":
        argv += ["--rig", str(SCENARIOS / f"{name}.yaml")]
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = rig_main(argv)
    return code, json.loads(out.getvalue())


def replay_matches(log: str) -> str:
    """`rig replay LOG --json`: how many trials' slip events the replay re-detected identically."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = rig_main(["replay", log, "--json"])
    if code != 0:
        return f"replay exit {code}"
    redetection = json.loads(out.getvalue()).get("redetection") or {}
    mismatches = redetection.get("mismatches") or []
    return f"replay re-detects {redetection.get('matches')}/{redetection.get('trials')}" + (
        f", mismatches {mismatches}" if mismatches else ""
    )


def detections_with_sample_times(parts: list[Any], offset_ns: int) -> list[tuple[SlipEvent, int]]:
    """Every logged slip event, with the true sampling time of the sample that detected it.

    The sample's device clock, shifted by the simulator's run-clock offset, is the world's time.
    """
    events: list[tuple[SlipEvent, int]] = []
    for part in parts:
        cell = part.log.topic(schemas.LOADCELL)
        stamps = cell["log_time_ns"].to_numpy()
        device_us = cell["device_time_us"].to_numpy()
        for _, payload in frame_payloads(part.log.topic(schemas.SLIP)):
            event = SlipMessage.from_payload(payload).event
            row = min(int(np.searchsorted(stamps, event.detection_time_ns)), len(stamps) - 1)
            events.append((event, offset_ns + int(device_us[row]) * 1000))
    return events


def score_run(report: dict[str, Any], scores: dict[str, Score]) -> None:
    """Match the run's detections with the truth's slip events, trial by trial (by time)."""
    parts = read_parts(report["log"])
    truth = run_settings(parts, [])
    assert truth.truth is not None, "the log has no sim_truth"
    world = truth.truth["world"]
    offset = world["run_clock_offset_ns"]
    events = detections_with_sample_times(parts, offset)
    trials = world["trials"]
    starts = [t["start_ns"] + offset for t in trials] + [math.inf]
    for trial, start, end in zip(trials, starts, starts[1:], strict=False):
        mine = [(e, sampled) for e, sampled in events if start <= e.detection_time_ns < end]
        score = scores[size_label(trial)]
        score.trials += 1
        truth_events = trial["slip_events"]
        detected, sampled_ns = mine[0] if mine else (None, 0)
        if not truth_events:
            score.early += detected is not None
            continue
        first = truth_events[0]
        if detected is None:
            score.misses += 1
        elif sampled_ns <= first["onset_time_ns"]:
            score.early += 1
        else:
            score.latencies.append(-((first["onset_time_ns"] - sampled_ns) // SAMPLE_NS))  # ceil
            score.biases_n.append(detected.peak_force_n - first["load_n"])
            score.relative_biases.append(detected.peak_force_n / first["load_n"] - 1)


def scenarios(seeds: list[int], names: list[str], protocol: Path = PROTOCOL) -> None:
    header = (
        "| kind (size) | trials | detected | latency median | p99 | max [samples] | misses | early "
        "| peak bias mean [mN] | max abs [mN] | max abs [%] |"
    )
    for name in names:
        scores: dict[str, Score] = defaultdict(Score)
        print(f"\n### {name}\n")
        for seed in seeds:
            with tempfile.TemporaryDirectory() as folder:
                code, report = run_scenario(name, seed, Path(folder), protocol)
                estimate = report.get("estimate") or {}
                k_true = report["truth"]["k"]
                ci = estimate.get("k_ci")
                inside = ci is not None and ci[0] <= k_true <= ci[1]
                outcomes: dict[str, int] = defaultdict(int)
                for trial in report["trials"]:
                    outcomes[str(trial["outcome"])] += 1
                k_text = f"{estimate['k']:.4f} [{ci[0]:.4f}, {ci[1]:.4f}]" if ci else "none"
                print(
                    f"seed {seed}: exit {code}, {report['completed']}/{report['planned']} trials "
                    f"({', '.join(f'{k} {v}' for k, v in sorted(outcomes.items()))}), k {k_text}, "
                    f"true {k_true:.4f}: {'inside' if inside else 'OUTSIDE'} the 99 % bounds; "
                    f"{replay_matches(report['log'])}"
                )
                score_run(report, scores)
        print()
        print(header)
        print("|" + "---|" * 11)
        for label in sorted(scores):
            print(scores[label].row(label))


# --------------------------------------------------------------------------------------- quiet

SEGMENT_SAMPLES = 10_000
TARE_SAMPLES = 100
HOLD_N = 2.5
RAMP_N_PER_S = 4.0


class QuietProfile:
    """Tension of the quiet segments: zero for the tare, a ramp at 4 N/s, a hold at 2.5 N."""

    def __init__(self, start_ns: int) -> None:
        self.start_ns = start_ns

    def __call__(self, t_ns: int) -> float:
        within_s = ((t_ns - self.start_ns) % (SEGMENT_SAMPLES * SAMPLE_NS)) * 1e-9
        ramp_s = within_s - TARE_SAMPLES / RATE_HZ
        return 0.0 if ramp_s <= 0 else min(HOLD_N, RAMP_N_PER_S * ramp_s)


def false_alarms(
    params: DetectorParams, artefacts: LoadCellArtefacts, samples: int, seed: int
) -> tuple[int, int]:
    """(false alarms, quiet samples fed to the detector) over `samples` samples of quiet segments."""
    preset = make_preset("link1", seed, loadcell_artefacts=artefacts)
    gain = SignalModel().gain_counts_per_n
    signal = SignalModel(noise_counts=preset.loadcell_noise_n * gain)
    model = None
    if artefacts.active:
        model = ArtefactModel(artefacts, int(stream_rng(seed, STREAM_LOADCELL_ARTEFACTS).integers(2**63)))
    emulator = LoadCellEmulator(QuietProfile(0), rate_hz=RATE_HZ, signal=signal, seed=seed, artefacts=model)
    decoder = LineDecoder(emulator.codec)
    alarms = fed = 0
    for segment in range(max(1, samples // SEGMENT_SAMPLES)):
        end_ns = ((segment + 1) * SEGMENT_SAMPLES - 1) * SAMPLE_NS
        lines = decoder.feed(b"".join(chunk for _, chunk in emulator.lines_until(end_ns)))
        forces = (np.array([ln.raw for ln in lines], dtype=float) - signal.offset_counts) / gain
        forces -= forces[:TARE_SAMPLES].mean()
        state = detector_init(params)
        base_ns = segment * SEGMENT_SAMPLES * SAMPLE_NS
        for i in range(TARE_SAMPLES, len(forces)):
            state, fired = detector_step(params, state, base_ns + i * SAMPLE_NS, float(forces[i]))
            fed += 1
            if fired is not None:
                alarms += 1
                state = detector_init(params)
    return alarms, fed


def quiet(samples: int, seed: int, protocol: Path = PROTOCOL) -> None:
    params = load_protocol(protocol).detector
    noisy = require_simulated(load_rig_config(SCENARIOS / "noisy-cell.yaml"))
    print("| load cell | quiet samples | false alarms | per 1e6 samples |")
    print("|---|---|---|---|")
    for label, artefacts in (("default (5 mN)", LoadCellArtefacts()), ("noisy-cell", noisy.loadcell)):
        alarms, fed = false_alarms(params, artefacts, samples, seed)
        print(f"| {label} | {fed} | {alarms} | {alarms / fed * 1e6:.2f} |")


# -------------------------------------------------------------------------------------- ratios


def run_ratio(ratio: float, before: bool, seed: int, protocol: Path = PROTOCOL) -> str:
    original: Callable[..., Any] = simulated_rig.make_preset
    presets_made = 0

    def patched(*args: Any, **kwargs: Any) -> Any:
        nonlocal presets_made
        presets_made += 1
        return dataclasses.replace(original(*args, **kwargs), kinetic_ratio=ratio)

    text = protocol.read_text()
    if before:
        text = text.replace("  drop_fraction: 0.15\n", "  drop_fraction: 0.15\n" + BEFORE, 1)
    out = io.StringIO()
    with tempfile.TemporaryDirectory() as folder:
        protocol = Path(folder, "protocol.yaml")
        protocol.write_text(text)
        simulated_rig.make_preset = patched  # type: ignore[assignment]
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
                code = rig_main(["run", str(protocol), "--seed", str(seed), "--json", "--out", folder])
        finally:
            simulated_rig.make_preset = original  # type: ignore[assignment]
    if not presets_made:  # the run got its preset elsewhere: the ratio would silently not apply
        raise SystemExit(
            "rig.sim.simulated_rig.make_preset was not called by the run: the ratio was not applied"
        )
    report = json.loads(out.getvalue())
    estimate = report.get("estimate") or {}
    k_ci = estimate.get("k_ci")
    bounds = f" [{k_ci[0]:.6f}, {k_ci[1]:.6f}]" if k_ci else ""
    k = f"{estimate['k']:.6f}" if "k" in estimate else "none"
    outcomes: dict[str, int] = {}
    for trial in report["trials"]:
        outcomes[trial["outcome"]] = outcomes.get(trial["outcome"], 0) + 1
    return (
        f"exit {code}, {report['completed']}/{report['planned']} trials {outcomes}, k {k}{bounds}, "
        f"true {report['truth']['k']:.6f}, {report.get('reason') or ''}"
    )


def ratios(values: list[float], seed: int, protocol: Path = PROTOCOL) -> None:
    for ratio in values:
        for before in (False, True):
            label = "before" if before else "defaults"
            result = run_ratio(ratio, before, seed, protocol)
            print(f"kinetic_ratio {ratio:g} ({1 - ratio:.0%} drop), {label}: {result}")


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("mode", nargs="?", default="ratios", choices=["scenarios", "quiet", "ratios"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="scenarios")
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIO_NAMES), choices=SCENARIO_NAMES)
    parser.add_argument("--samples", type=int, default=1_000_000, help="quiet: samples per load cell")
    parser.add_argument("--ratios", type=float, nargs="+", default=[0.8, 0.9, 0.95], help="ratios")
    parser.add_argument("--seed", type=int, default=0, help="quiet, ratios")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP + "; every mode")
    args = parser.parse_args()
    if args.smoke:  # every mode, on a two-trial copy of the protocol (an estimate): one scenario, one ratio
        with tempfile.TemporaryDirectory() as folder:
            protocol = short_protocol(Path(folder))
            scenarios([0], ["mixed"], protocol)
            quiet(SEGMENT_SAMPLES, args.seed, protocol)  # one segment per load cell
            ratios([0.8], args.seed, protocol)  # 0.8: the old detector's ramps do not time out
        return
    if args.mode == "scenarios":
        scenarios(args.seeds, args.scenarios)
    elif args.mode == "quiet":
        quiet(args.samples, args.seed)
    else:
        ratios(args.ratios, args.seed)


if __name__ == "__main__":
    main()
