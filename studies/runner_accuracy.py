"""Statistical behaviour of `rig run` on the simulated rig over many seeds (the issue's acceptance checks).

* joint estimation: how often the 99 % bounds on k cover the simulator's true k, and how far the
  estimate is from it;
* link validation: the share of percentage errors below 15 % (paper: 80.4 %), mean and sd.

    .venv/bin/python studies/runner_accuracy.py [--seeds 20] [--link-seeds 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from rig.rigs import open_rig
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress

ROOT = Path(__file__).resolve().parent.parent


def run(protocol: str, seed: int, out: Path):
    request = RunRequest(
        protocol_path=ROOT / "protocols" / protocol,
        rig_path=None,
        out_dir=out,
        seed=seed,
        run_id=f"{Path(protocol).stem}-{seed}",
    )
    prepared = prepare_run(request)
    return execute_run(prepared, open_rig(prepared), SilentProgress())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20, help="joint-estimation runs")
    parser.add_argument("--link-seeds", type=int, default=5, help="link-validation runs")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        if args.seeds > 0:
            joint_estimation_accuracy(args.seeds, out)
        if args.link_seeds > 0:
            link_validation_accuracy(args.link_seeds, out)


def joint_estimation_accuracy(seeds: int, out: Path) -> None:
    """Coverage of the 99 % bounds on k and the estimate's error over `seeds` runs.

    For the protocol's estimator and for the paper's fit of the same trials, side by side.
    """
    fits: dict[str, list] = {}
    for seed in range(seeds):
        report = run("joint_estimation.yaml", seed, out)
        detail, k_true = report.estimate_detail, report.truth.k_kg_m
        chosen = f"{detail.estimate.estimator} (the run's)"
        for name, est in ((chosen, detail.fit), ("paper's fit", detail.paper)):
            fits.setdefault(name, []).append((est, k_true))
    print(f"joint estimation, {seeds} seeds (24 trials each):")
    for name, rows in fits.items():
        covered = sum(est.k_ci[0] <= k_true <= est.k_ci[1] for est, k_true in rows)
        errors = [(est.k - k_true) / k_true * 100 for est, k_true in rows]
        print(f"  {name}: 99 % bounds cover the true k in {covered}/{seeds} runs")
        print(
            f"    estimate error: mean {statistics.mean(errors):+.2f} %, mean |error| "
            f"{statistics.mean(abs(e) for e in errors):.2f} %, "
            f"max |error| {max(abs(e) for e in errors):.2f} %"
        )
        print(f"    RMSE: median {statistics.median(est.rmse for est, _ in rows):.3f} kg (paper 0.126 kg)")


def link_validation_accuracy(seeds: int, out: Path) -> None:
    """Table IV statistics of the percentage errors over `seeds` runs."""
    shares, means, stds, all_pct = [], [], [], []
    for seed in range(seeds):
        report = run("link_validation.yaml", seed, out)
        pe = report.percentage_errors.to_dict()
        shares.append(pe["share_below_pct"]["15"])
        means.append(pe["mean_pct"])
        stds.append(pe["std_pct"])
        all_pct += pe["percentage_errors"]
    print(f"link validation, {seeds} seeds (21 configurations each):")
    print("  share of percentage errors below 15 % per run: " + ", ".join(f"{s * 100:.1f} %" for s in shares))
    pooled = sum(p < 15 for p in all_pct) / len(all_pct)
    print(f"  pooled: {pooled * 100:.1f} % of {len(all_pct)} errors below 15 % (paper: 80.4 %)")
    print(
        f"  mean percentage error per run: {', '.join(f'{m:.2f}' for m in means)} % "
        f"(sd {', '.join(f'{s:.2f}' for s in stds)}) (paper: 9.53 +- 6.73 and 12.5 +- 10.5)"
    )


if __name__ == "__main__":
    main()
