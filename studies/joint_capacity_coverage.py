"""Coverage of the per-joint capacity bounds a run gives after link validation (the runner's own glue).

Synthetic, no devices: it follows the simulated rig's model of the test article (rig.sim's link1
preset) and feeds the trials through `rig.runner.run_estimates.RunEstimator`, the very code a run uses:

* true joint capacities C_j = C0·(1 + 0.10·z_j) (z clipped to ±3; C0 = 0.1615 kg·m · 9.8 m/s²), the
  joint-estimation specimen at C0;
* joint estimation as in protocols/link_validation.yaml (0.03-0.25 m x 8 x 2), slip masses
  C0·(1 + s·z)/(g·l) with s = 0.085 the per-trial capacity scatter; the protocol's estimator fits them;
* the 21 configurations of protocols/link_validation.yaml: in each trial every joint resists up to
  C_j·(1 + s·z_j); the link slips at f = min_j of that over its lever arm, and the slipped joint is
  reported with probability 0.8 (else unknown), as the simulator does. Lever arms are the exact
  ones of the commanded configuration (no bend or measurement error: a simplification).

Printed: the share of (run, joint) pairs whose 99 % bounds hold the true capacity, with its 95 %
Wilson interval, and the share of runs where all 8 do.

    .venv/bin/python studies/joint_capacity_coverage.py [--runs 400] [--seed 0] [--estimator auto]
        [--obs-sd-log S]   (hold the filter's trial-to-trial scatter at S instead of the runner's choice)
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import yaml

from model.chain import lever_arms_m, planar_transforms
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, load_rig_config
from rig.runner.run_estimates import RunEstimator

REPO = Path(__file__).resolve().parents[1]
K_NOMINAL = 0.1615  # kg·m (link 1)
G = 9.8
JOINT_SPREAD_SD = 0.10
PER_TRIAL_SD = 0.085
REPORT_PROBABILITY = 0.8


def wilson(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval of a binomial proportion."""
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    return centre - half, centre + half


class FixedScatterEstimator(RunEstimator):
    """The runner's estimator with the per-joint filter's scatter held at a given value."""

    obs_sd_log = 0.05

    def _trial_scatter_log(self) -> float:
        return self.obs_sd_log


def one_run(
    rng: np.random.Generator,
    estimator: str,
    configurations: np.ndarray,
    distances: list[float],
    obs_sd_log: float | None = None,
) -> np.ndarray:
    """Whether each joint's 99 % bounds hold its true capacity after one synthetic run."""
    article = load_rig_config(DEFAULT_RIG_CONFIG).article
    joints = article.joint_count
    c0 = K_NOMINAL * G
    capacities = c0 * (1 + JOINT_SPREAD_SD * np.clip(rng.standard_normal(joints), -3, 3))
    run = (
        RunEstimator(article, estimator=estimator)  # type: ignore[arg-type]
        if obs_sd_log is None
        else FixedScatterEstimator(article, estimator=estimator)  # type: ignore[arg-type]
    )
    if isinstance(run, FixedScatterEstimator) and obs_sd_log is not None:
        run.obs_sd_log = obs_sd_log
    for d in rng.permutation(distances):
        factor = 1 + PER_TRIAL_SD * np.clip(rng.standard_normal(), -3, 3)
        run.update_joint_estimation(float(d), c0 * factor / (G * d))
    for angles in configurations:
        transforms = planar_transforms(angles, np.asarray(article.segment_lengths_m))
        arms = lever_arms_m(transforms, np.asarray(article.point_m), np.asarray(article.direction))[1:]
        resist = capacities * (1 + PER_TRIAL_SD * np.clip(rng.standard_normal(joints), -3, 3))
        ratio = np.where(arms > 0, resist / np.where(arms > 0, arms, 1.0), np.inf)
        weakest = int(np.argmin(ratio))
        reported = weakest + 1 if rng.random() < REPORT_PROBABILITY else None
        run.update_link(arms, float(ratio[weakest]), reported)
    caps = run.joint_capacities()
    assert caps is not None
    covered: np.ndarray = (caps.ci_lo_nm <= capacities) & (capacities <= caps.ci_hi_nm)
    return covered


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--runs", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--estimator", default="auto", choices=("paper", "weighted", "auto"))
    parser.add_argument("--obs-sd-log", type=float, default=None)
    args = parser.parse_args()
    protocol = yaml.safe_load((REPO / "protocols" / "link_validation.yaml").read_text())
    joint_block, link_block = protocol["blocks"]
    distances = [float(d) for d in joint_block["distances_m"]] * int(joint_block.get("repeats", 1))
    configurations = np.radians(np.asarray(link_block["configurations_deg"], float))
    rng = np.random.default_rng(args.seed)
    covered = np.array(
        [one_run(rng, args.estimator, configurations, distances, args.obs_sd_log) for _ in range(args.runs)]
    )
    hits, total = int(covered.sum()), covered.size
    lo, hi = wilson(hits, total)
    per_joint = ", ".join(f"{v:.3f}" for v in covered.mean(axis=0))
    scatter = "the runner's" if args.obs_sd_log is None else f"held at {args.obs_sd_log}"
    print(
        f"estimator {args.estimator}, filter scatter {scatter}, {args.runs} runs x {covered.shape[1]} joints"
    )
    print(f"coverage {hits / total:.4f} [{lo:.4f}, {hi:.4f}] (95 % Wilson); per joint: {per_joint}")
    print(f"runs with all joints covered: {covered.all(axis=1).mean():.3f}")


if __name__ == "__main__":
    main()
