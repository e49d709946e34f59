"""Coverage and efficiency of every estimator of k on the simulated rig, per scatter shape and design.

Runs `rig study` (object-level devices, worker processes) for each scatter shape the simulator has
(multiplicative: the built-in rig; additive and mixed: protocols/rigs/scenarios/*-scatter.yaml) on
both joint-estimation designs (the paper's 8 distances over 0.03-0.25 m, protocols/joint_estimation.yaml,
and the narrower 0.10-0.25 m, the same protocol with its distances replaced), and prints one
markdown table: per case and estimator, the coverage of the 99 % bounds with its 95 % interval,
MSE over the Cramér-Rao bound, and the relative bias.

    .venv/bin/python studies/estimators_end_to_end.py [--seeds 0-199] [--jobs 2] [--keep DIR]
        [--designs 0.03-0.25 0.10-0.25] [--shapes multiplicative additive mixed]
    .venv/bin/python studies/estimators_end_to_end.py --refit DIR [--designs ...] [--shapes ...]

`--keep DIR` keeps each case's `rig study` table as DIR/<design>-<shape>/study.parquet. `--refit DIR`
runs nothing: it refits today's estimators to the trials those tables hold (the same scoring as
`rig study`), e.g. after an estimator changed, without rerunning the rig.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import pyarrow.parquet as pq
import yaml

from model.fit import DEFAULT_LEVEL
from model.k_estimators import ESTIMATOR_NAMES
from rig.study.statistics import summarise
from rig.study.worker import RunRecord, score_joint

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL = ROOT / "protocols" / "joint_estimation.yaml"
SCENARIOS = ROOT / "protocols" / "rigs" / "scenarios"
SHAPES = {
    "multiplicative": None,  # the built-in rig
    "additive": SCENARIOS / "additive-scatter.yaml",
    "mixed": SCENARIOS / "mixed-scatter.yaml",
}
DESIGNS = ("0.03-0.25", "0.10-0.25")  # the paper's (the shipped protocol) and the narrow one
DESIGN_LABELS = {"0.03-0.25": "paper", "0.10-0.25": "narrow"}  # directory names under --keep
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


def study(protocol: Path, rig: Path | None, seeds: str, jobs: int, out: Path | None) -> dict[str, object]:
    """`rig study --json` of one case (its table in `out` when given)."""
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
    if out is not None:
        command += ["--out", str(out)]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{' '.join(command)}: exit {done.returncode}\n{done.stderr}")
    result: dict[str, object] = json.loads(done.stdout)
    return result


def refit_case(table: Path) -> dict[str, object]:
    """`rig study --json`'s summary of a kept table, with today's estimators refitted to its trials."""
    rows = pq.read_table(table).to_pylist()
    records = []
    for seed in sorted({row["seed"] for row in rows}):
        runs = [row for row in rows if row["seed"] == seed]
        first = runs[0]
        joints = tuple(
            replace(
                score_joint(
                    row["joint"],
                    row["k_true_kg_m"],
                    (row["true_scatter_a_kg"], row["true_scatter_b"]),
                    row["distances_m"],
                    row["masses_kg"],
                    row["censored"],
                    DEFAULT_LEVEL,
                ),
                n_excluded=row["n_excluded"],
            )
            for row in {row["joint"]: row for row in runs if row["joint"] is not None}.values()
        )
        records.append(
            RunRecord(
                seed,
                first["status"],
                first["reason"],
                first["trials_planned"],
                first["trials_completed"],
                first["wall_s"],
                joints,
            )
        )
    summary = summarise(str(table), [r.seed for r in records], records, ESTIMATOR_NAMES, DEFAULT_LEVEL)
    return summary.as_json()


def print_row(design: str, shape: str, result: dict[str, object]) -> None:
    """The markdown rows of one case, one per estimator."""
    estimators = result["estimators"]
    assert isinstance(estimators, dict)
    for name, row in estimators.items():
        lo, hi = row["coverage_ci"]
        print(
            f"| {design} m | {shape} | {name} | {result['runs']} ({result['aborted']}) "
            f"| {row['coverage']:.4f} [{lo:.4f}, {hi:.4f}] | {row['mse_over_crlb']:.3f} "
            f"| {100 * row['bias_rel']:+.2f} % |",
            flush=True,
        )


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
    parser.add_argument("--keep", type=Path, help="keep each case's study table under this directory")
    parser.add_argument("--refit", type=Path, help="refit the tables kept under this directory; run nothing")
    args = parser.parse_args()
    print("| design | scatter | estimator | runs (aborted) | coverage [95 % CI] | MSE / CRLB | bias |")
    print("|---|---|---|---|---|---|---|")
    if args.refit is not None:
        for design in args.designs:
            for shape in args.shapes:
                table = args.refit / f"{DESIGN_LABELS[design]}-{shape}" / "study.parquet"
                if not table.is_file():
                    sys.exit(f"{table}: no such table; allowed: a directory written by --keep")
                print_row(design, shape, refit_case(table))
        return
    with tempfile.TemporaryDirectory() as tmp:
        protocols = {"0.03-0.25": PROTOCOL, "0.10-0.25": narrow_protocol(Path(tmp))}
        for design in args.designs:
            for shape in args.shapes:
                out = None if args.keep is None else args.keep / f"{DESIGN_LABELS[design]}-{shape}"
                print_row(design, shape, study(protocols[design], SHAPES[shape], args.seeds, args.jobs, out))


if __name__ == "__main__":
    main()
