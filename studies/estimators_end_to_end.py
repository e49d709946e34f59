"""Coverage and efficiency of every estimator of k on the simulated rig, per scatter shape and design.

Runs `rig study` (object-level devices, worker processes) for each scatter shape the simulator has
(multiplicative: the built-in rig; additive and mixed: protocols/rigs/scenarios/*-scatter.yaml) on
both joint-estimation designs (the paper's 8 distances over 0.03-0.25 m, protocols/joint_estimation.yaml,
and the narrower 0.10-0.25 m, the same protocol with its distances replaced), and prints one
markdown table: per case and estimator, the coverage of the 99 % bounds with its 95 % interval,
MSE over the Cramér-Rao bound, and the relative bias.

    .venv/bin/python studies/estimators_end_to_end.py [--seeds 0-199] [--jobs 2]
        [--designs 0.03-0.25 0.10-0.25] [--shapes multiplicative additive mixed]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL = ROOT / "protocols" / "joint_estimation.yaml"
SCENARIOS = ROOT / "protocols" / "rigs" / "scenarios"
SHAPES = {
    "multiplicative": None,  # the built-in rig
    "additive": SCENARIOS / "additive-scatter.yaml",
    "mixed": SCENARIOS / "mixed-scatter.yaml",
}
DESIGNS = ("0.03-0.25", "0.10-0.25")  # the paper's (the shipped protocol) and the narrow one
NARROW_DISTANCES_M = [0.10, 0.1214, 0.1429, 0.1643, 0.1857, 0.2071, 0.2286, 0.25]


def narrow_protocol(directory: Path) -> Path:
    """The shipped protocol with the 0.10-0.25 m distances (the design before the paper's was restored)."""
    data = yaml.safe_load(PROTOCOL.read_text())
    for block in data["blocks"]:
        if block.get("kind") == "joint_estimation":
            block["distances_m"] = NARROW_DISTANCES_M
    data["name"] = "joint_estimation_narrow"
    path = directory / "joint_estimation_narrow.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def study(protocol: Path, rig: Path | None, seeds: str, jobs: int) -> dict[str, object]:
    """`rig study --json` of one case."""
    command = [
        sys.executable,
        "-m",
        "rig.cli",
        "study",
        str(protocol),
        "--seeds",
        seeds,
        "--jobs",
        str(jobs),
        "--json",
    ]
    if rig is not None:
        command += ["--rig", str(rig)]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{' '.join(command)}: exit {done.returncode}\n{done.stderr}")
    result: dict[str, object] = json.loads(done.stdout)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-199", help="seeds per case, `rig study` syntax (default 0-199)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument(
        "--designs", nargs="+", choices=DESIGNS, default=list(DESIGNS), help="designs to run (default both)"
    )
    parser.add_argument(
        "--shapes", nargs="+", choices=list(SHAPES), default=list(SHAPES), help="scatter shapes (default all)"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        protocols = {"0.03-0.25": PROTOCOL, "0.10-0.25": narrow_protocol(Path(tmp))}
        print("| design | scatter | estimator | runs (aborted) | coverage [95 % CI] | MSE / CRLB | bias |")
        print("|---|---|---|---|---|---|---|")
        for design in args.designs:
            for shape in args.shapes:
                result = study(protocols[design], SHAPES[shape], args.seeds, args.jobs)
                estimators = result["estimators"]
                assert isinstance(estimators, dict)
                for name, row in estimators.items():
                    lo, hi = row["coverage_ci"]
                    print(
                        f"| {design} m | {shape} | {name} | {result['runs']} ({result['aborted']}) "
                        f"| {row['coverage']:.3f} [{lo:.3f}, {hi:.3f}] | {row['mse_over_crlb']:.2f} "
                        f"| {100 * row['bias_rel']:+.2f} % |",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
