"""The line compliance a low-rate lab needs to read slip loads within 0.5 % (issue 21): a measured table.

Run (from the repository root, with the project's environment):

    python benchmarks/bench_line_compliance.py [--rate 10] [--springs none 2000 1000] [--seeds 0 1 2]

One servo count of the winch (2π/4096 rad) is q = k·r·2π/4096 of tension on a line of stiffness k and
a spool of radius r: 77 mN on the simulated rig's 5000 N/m line and 10 mm spool. A ramp stepped count
by count (below one Profile Velocity unit, as at 10/s) reads the slip load only to within q
(rig/runner/ramp_speed.py). Each row is `rig run protocols/joint_estimation.yaml --seed S` on the
built-in simulated rig at `--rate` with a spring of that stiffness in series with the line
(`simulation.spring_stiffness_n_per_m`; `none`: the line alone) and the rig's nominal
`line_stiffness_n_per_m` set to the series stiffness. The protocol's winch speeds (rad/s) are
multiplied by 5000 N/m / the series stiffness, so that the ramp's newtons per second are the stiff
line's, the fast and unload speeds at most `MAX_WINCH_RAD_S` (the XM430-W350 runs 4.8 rad/s with no
load). Scored as bench_rates.py does (slip-load error, lag, run time), with q and q over the run's
smallest true slip load.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from bench_rates import score  # benchmarks/ is the script's directory
from smoke_mode import SMOKE_HELP, short_protocol

from rig.analysis.runlog import read_parts, run_settings
from rig.cli import main as rig_main
from rig.hw.dxl.units import RAD_PER_PULSE

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL = ROOT / "protocols" / "joint_estimation.yaml"
LINE_N_PER_M = 5000.0  # the simulated preset's line
SPOOL_M = 0.01
MAX_WINCH_RAD_S = 4.0


def series_n_per_m(spring: float | None) -> float:
    """The line and the spring in series."""
    return LINE_N_PER_M if spring is None else 1.0 / (1.0 / LINE_N_PER_M + 1.0 / spring)


def scaled_protocol(factor: float, source: Path = PROTOCOL) -> str:
    """The default protocol (or `source`) with its winch speeds times `factor` (fast and unload capped)."""
    data = yaml.safe_load(source.read_text())
    ramp = data["ramp"]
    ramp["slow_speed_rad_s"] = ramp["slow_speed_rad_s"] * factor
    ramp["fast_speed_rad_s"] = min(MAX_WINCH_RAD_S, ramp["fast_speed_rad_s"] * factor)
    ramp["unload_speed_rad_s"] = min(MAX_WINCH_RAD_S, ramp.get("unload_speed_rad_s", 2.0) * factor)
    return yaml.safe_dump(data, sort_keys=False)


def run(
    rate_hz: float, spring: float | None, seed: int, folder: Path, source: Path = PROTOCOL
) -> tuple[int, dict[str, Any]]:
    """One run at `rate_hz` with `spring` in series; (exit code, report)."""
    k = series_n_per_m(spring)
    rig = folder / "rig.yaml"
    spring_line = "" if spring is None else f"  spring_stiffness_n_per_m: {spring:g}\n"
    rig.write_text(
        f"extends: simulated\nname: compliance\nline_stiffness_n_per_m: {k:.6g}\n"
        f"simulation:\n  loadcell_rate_hz: {rate_hz:g}\n{spring_line}"
    )
    protocol = folder / "protocol.yaml"
    protocol.write_text(scaled_protocol(LINE_N_PER_M / k, source))
    argv = ["run", str(protocol), "--rig", str(rig), "--seed", str(seed), "--json", "--out", str(folder)]
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = rig_main(argv)
    return code, json.loads(out.getvalue())


def smallest_slip_n(report: dict[str, Any]) -> float:
    """The run's smallest true first-slip load."""
    world = run_settings(read_parts(report["log"]), []).truth
    assert world is not None
    return min(t["slip_events"][0]["load_n"] for t in world["world"]["trials"] if t["slip_events"])


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--rate", type=float, default=10.0)
    parser.add_argument("--springs", nargs="+", default=["none", "2000", "1000"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:  # the line alone and with a spring, one seed, a one-trial copy of the protocol
        args.springs, args.seeds = ["none", "1000"], [0]
    print(
        "| spring [N/m] | series k [N/m] | q [mN] | seed | outcomes | smallest slip [N] | q / it [%] "
        "| error < 0.5 % | error mean, max abs [%] | lag <= 2 | run time [s] |"
    )
    print("|" + "---|" * 11)
    for text in args.springs:
        spring = None if text == "none" else float(text)
        k = series_n_per_m(spring)
        q_n = k * SPOOL_M * RAD_PER_PULSE
        for seed in args.seeds:
            with tempfile.TemporaryDirectory() as folder:
                source = (
                    short_protocol(Path(folder), name="source.yaml", trials=1) if args.smoke else PROTOCOL
                )
                code, report = run(args.rate, spring, seed, Path(folder), source)
                lags, errors, _ = score(report, args.rate)
                smallest = smallest_slip_n(report)
            trials = report["trials"]
            span_s = (trials[-1]["end_time_ns"] - trials[0]["start_time_ns"]) / 1e9
            outcomes = Counter(str(t["outcome"]) for t in trials)
            err = np.array(errors) * 100
            outcome_text = ", ".join(f"{o} {n}" for o, n in sorted(outcomes.items()))
            if code != 0:
                outcome_text += f" (exit {code})"
            within = int(np.sum(np.abs(err) < 0.5))
            print(
                f"| {text} | {k:.0f} | {q_n * 1000:.1f} | {seed} | {outcome_text} "
                f"| {smallest:.2f} | {q_n / smallest * 100:.2f} | {within}/{err.size} "
                f"| {err.mean():+.3f}, {np.abs(err).max():.3f} | {sum(n <= 2 for n in lags)}/{len(lags)} "
                f"| {span_s:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
