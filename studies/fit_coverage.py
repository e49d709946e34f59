"""How often cftool's 99 % bounds on k cover the true k, for a joint-estimation design and a noise model.

Bare statistics, no simulator: slip masses m = k/l · (1 + s·e1) + a·e2 (e1, e2 standard normal;
s the relative trial-to-trial scatter of the capacity, a an additive scatter in kg), fitted by the
one-parameter least squares of docs/model.md §4 (`model.fit.fit_inverse_distance`, vectorised here over
the data sets and checked against it on the first few). Prints coverage, median RMSE and the mean
|error| of k for each design.

    .venv/bin/python studies/fit_coverage.py [--datasets 20000] [--relative-sd 0.085] [--additive-kg 0]
"""

from __future__ import annotations

import argparse

import numpy as np

from model.fit import fit_inverse_distance, t_quantile

K_TRUE = 0.1615  # link 1 of the paper [kg·m]
DESIGNS = {  # name: (distances [m], repeats)
    "0.03-0.25 m, 8 x 3 (old protocol)": (np.linspace(0.03, 0.25, 8), 3),
    "0.05-0.25 m, 8 x 3": (np.linspace(0.05, 0.25, 8), 3),
    "0.08-0.25 m, 8 x 3": (np.linspace(0.08, 0.25, 8), 3),
    "0.10-0.25 m, 8 x 3 (joint_estimation.yaml)": (np.linspace(0.10, 0.25, 8), 3),
    "0.03-0.25 m, 8 x 1 (paper-like)": (np.linspace(0.03, 0.25, 8), 1),
}


def coverage(
    distances_m: np.ndarray, repeats: int, relative_sd: float, additive_kg: float, datasets: int, seed: int
) -> tuple[float, float, float]:
    """(coverage of the 99 % bounds, median RMSE [kg], mean |k error| [%]) over `datasets` fits."""
    rng = np.random.default_rng(seed)
    x = np.repeat(1.0 / distances_m, repeats)
    n = len(x)
    m = K_TRUE * x * (1 + relative_sd * rng.standard_normal((datasets, n)))
    m += additive_kg * rng.standard_normal((datasets, n))
    k = m @ x / (x @ x)
    rmse = np.sqrt(((m - k[:, None] * x) ** 2).sum(axis=1) / (n - 1))
    half_width = t_quantile(0.99, n - 1) * rmse / np.sqrt(x @ x)
    for i in range(3):  # the vectorised fit is the project's fit
        reference = fit_inverse_distance(np.repeat(distances_m, repeats), m[i], level=0.99)
        assert np.isclose(reference.k, k[i], rtol=1e-12) and np.isclose(reference.rmse, rmse[i], rtol=1e-9)
        assert np.isclose(reference.k_ci[1] - reference.k, half_width[i], rtol=1e-9)
    covered = np.abs(k - K_TRUE) <= half_width
    return float(covered.mean()), float(np.median(rmse)), float(np.mean(np.abs(k / K_TRUE - 1)) * 100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=20_000)
    parser.add_argument("--relative-sd", type=float, default=0.085, help="s (the simulator's link1: 0.085)")
    parser.add_argument("--additive-kg", type=float, default=0.0, help="a")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"s = {args.relative_sd}, a = {args.additive_kg} kg, {args.datasets} data sets per design")
    for name, (distances, repeats) in DESIGNS.items():
        cov, rmse, err = coverage(
            distances, repeats, args.relative_sd, args.additive_kg, args.datasets, args.seed
        )
        print(f"  {name:<44} coverage {cov * 100:5.1f} %   RMSE {rmse:.3f} kg   mean |error| {err:.2f} %")


if __name__ == "__main__":
    main()
