"""Where the slip-load error at low load-cell rates comes from: the ramp's rise per sample, or a servo count.

Command (from the repository root):

    .venv/bin/python studies/slip_load_floor.py [--rates 10 80] [--seeds 0 1 2] [--rig CONFIG]

Each run is `rig run protocols/joint_estimation.yaml --seed S` on the built-in simulated rig with only
`simulation.loadcell_rate_hz` changed (or, with `--rig`, on that rig config, whose rate is its own).
Per trial with a slip, against `sim_truth`'s first slip (load L, onset t0) and the log:

* error: the detected peak / L − 1 (what bench_rates.py scores);
* gap: L − the last sample before t0, over L (the sampling's share of the error);
* rise: the last sample-to-sample rise before t0, over L (how fast the ramp came, per sample);
* q/L: one servo count's tension (line stiffness × spool radius × 2π/4096) over L;
* stepped: the winch's goal was written count by count (a step of at most 2 counts) in the second
  before t0, i.e. the ramp was below one Profile Velocity unit.

A trial over 0.5 % is put down to the **count** when the ramp was stepped and the gap is within q
(plus 3 σ of the cell's noise), to the **ramp** when it was not stepped and the gap is within one
sample's rise (plus the noise), else **other**. The summary counts them per run; `--trials` prints
every trial over 0.5 %.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import tempfile
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rig.analysis.runlog import read_parts, run_settings
from rig.cli import main as rig_main
from rig.hw.dxl.units import RAD_PER_PULSE
from rig.inputs.rig_config import load_rig_config, nominal_loadcell_rate_hz
from rig.log.format import schemas
from rig.log.reading.frames import frame_payloads
from rig.records import SlipMessage

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL = ROOT / "protocols" / "joint_estimation.yaml"
TARGET = 0.005
NOISE_SIGMAS = 3.0


@dataclass(frozen=True)
class TrialFloor:
    """One trial's slip-load error and what it is made of (relative to the true slip load)."""

    trial: int
    load_n: float
    error: float
    gap: float
    rise: float
    count: float
    stepped: bool

    def cause(self, noise_rel: float) -> str:
        """'count', 'ramp' or 'other' (see the module docstring)."""
        if self.stepped and self.gap <= self.count + noise_rel:
            return "count"
        if not self.stepped and self.gap <= self.rise + noise_rel:
            return "ramp"
        return "other"


def run(rig_text: str, seed: int, folder: Path) -> dict[str, Any]:
    """`rig run` of the default protocol on the rig config `rig_text`; its --json report."""
    rig = folder / "rig.yaml"
    rig.write_text(rig_text)
    argv = ["run", str(PROTOCOL), "--rig", str(rig), "--seed", str(seed), "--json", "--out", str(folder)]
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        rig_main(argv)
    report: dict[str, Any] = json.loads(out.getvalue())
    return report


def trial_floors(report: dict[str, Any]) -> tuple[list[TrialFloor], float]:
    """Every slip trial's `TrialFloor`, and the cell's noise [N] from sim_truth."""
    parts = read_parts(report["log"])
    world = run_settings(parts, []).truth
    assert world is not None, "the log has no sim_truth"
    world = world["world"]
    offset = world["run_clock_offset_ns"]
    line = world["line"]
    count_n = line["effective_stiffness_n_per_m"] * line["drum_radius_m"] * RAD_PER_PULSE
    floors: list[TrialFloor] = []
    for part in parts:
        cell = part.log.topic(schemas.LOADCELL)
        sampled_ns = cell["device_time_us"].to_numpy() * 1000 + offset  # the world's time of each sample
        stamps = cell["log_time_ns"].to_numpy()
        forces = cell["force_n"].to_numpy()
        commands = part.log.topic(schemas.SERVO_COMMAND)
        goals = commands[(commands["role"] == "winch") & (commands["command"] == "goal_position")]
        goal_ns = goals["log_time_ns"].to_numpy()
        goal_rad = goals["value"].to_numpy()
        events = [SlipMessage.from_payload(p).event for _, p in frame_payloads(part.log.topic(schemas.SLIP))]
        starts = [t["start_ns"] + offset for t in world["trials"]] + [math.inf]
        for index, (trial, start, end) in enumerate(zip(world["trials"], starts, starts[1:], strict=False)):
            mine = [e for e in events if start <= e.detection_time_ns < end]
            if not mine or not trial["slip_events"]:
                continue
            first = trial["slip_events"][0]
            onset, load = first["onset_time_ns"], first["load_n"]
            before = np.flatnonzero((sampled_ns <= onset) & (stamps >= start))
            if before.size < 2:
                continue
            window = (goal_ns <= onset) & (goal_ns > onset - 1_000_000_000)
            steps = np.abs(np.diff(goal_rad[window])) / RAD_PER_PULSE
            floors.append(
                TrialFloor(
                    trial=index + 1,
                    load_n=load,
                    error=mine[0].peak_force_n / load - 1.0,
                    gap=(load - forces[before[-1]]) / load,
                    rise=(forces[before[-1]] - forces[before[-2]]) / load,
                    count=count_n / load,
                    stepped=bool(steps.size >= 2 and np.all(steps <= 2.0)),
                )
            )
    return floors, float(world["noise"]["loadcell_noise_n"])


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--rates", type=float, nargs="+", default=[10.0, 80.0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--rig", type=Path, help="a simulated rig config (its rate; --rates ignored)")
    parser.add_argument("--trials", action="store_true", help="print every trial over 0.5 %%")
    args = parser.parse_args()
    if args.rig is not None:
        rigs = [(nominal_loadcell_rate_hz(load_rig_config(args.rig)), args.rig.read_text(), args.rig.name)]
    else:
        rigs = [
            (rate, f"extends: simulated\nname: rate{rate:g}\nsimulation:\n  loadcell_rate_hz: {rate:g}\n", "")
            for rate in args.rates
        ]
    print(
        "| rig | rate [/s] | seed | q [mN] | trials | error > 0.5 % | of them: count, ramp, other "
        "| worst error [%] (its L [N], q/L [%], stepped) |"
    )
    print("|" + "---|" * 8)
    for rate, text, name in rigs:
        for seed in args.seeds:
            with tempfile.TemporaryDirectory() as folder:
                floors, noise_n = trial_floors(run(text, seed, Path(folder)))
            over = [f for f in floors if abs(f.error) >= TARGET]
            causes = Counter(f.cause(NOISE_SIGMAS * noise_n / f.load_n) for f in over)
            worst = max(floors, key=lambda f: abs(f.error))
            q_mn = worst.count * worst.load_n * 1000
            print(
                f"| {name or 'simulated'} | {rate:g} | {seed} | {q_mn:.1f} | {len(floors)} | {len(over)} "
                f"| {causes['count']}, {causes['ramp']}, {causes['other']} "
                f"| {worst.error * 100:+.2f} ({worst.load_n:.2f}, {worst.count * 100:.2f}, "
                f"{'yes' if worst.stepped else 'no'}) |",
                flush=True,
            )
            if args.trials:
                for f in over:
                    print(
                        f"    trial {f.trial}: L {f.load_n:.3f} N, error {f.error * 100:+.2f} %, gap "
                        f"{f.gap * 100:.2f} %, rise {f.rise * 100:.2f} %, q/L {f.count * 100:.2f} %, "
                        f"stepped {f.stepped}: {f.cause(NOISE_SIGMAS * noise_n / f.load_n)}"
                    )


if __name__ == "__main__":
    main()
