"""The seeded default run with the simulator's kinetic ratio patched: does the detector see smaller slips?

Run: .venv/bin/python benchmarks/bench_detector_sim.py [--ratios 0.8 0.9 0.95] [--seed 0]

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
import tempfile
from pathlib import Path
from typing import Any

import rig.sim.simulated_rig as simulated_rig
from rig.cli import main as rig_main

PROTOCOL = Path(__file__).resolve().parent.parent / "protocols" / "joint_estimation.yaml"
BEFORE = "  noise_k: null\n  creep_k: null\n  spike_samples: 1\n  train_k: null\n  drop_leak_n_per_s: 0\n"


def run(ratio: float, before: bool, seed: int) -> str:
    original = simulated_rig.make_preset

    def patched(*args: Any, **kwargs: Any) -> Any:
        return dataclasses.replace(original(*args, **kwargs), kinetic_ratio=ratio)

    text = PROTOCOL.read_text()
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
            simulated_rig.make_preset = original
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ratios", type=float, nargs="+", default=[0.8, 0.9, 0.95])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for ratio in args.ratios:
        for before in (False, True):
            label = "before" if before else "defaults"
            print(f"kinetic_ratio {ratio:g} ({1 - ratio:.0%} drop), {label}: {run(ratio, before, args.seed)}")


if __name__ == "__main__":
    main()
