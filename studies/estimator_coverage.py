"""Coverage of the 99 % bounds on k and MSE against the Cramér-Rao bound, for paper, weighted and auto.

Bare statistics, no simulator: for each design and scatter model, `--datasets` synthetic data sets
m_i = k/l_i + e_i with e_i ~ N(0, a² + (b·k/l_i)²) (k = 0.1615 kg·m, link 1 of the paper) are fitted by
the three estimators of `model.k_estimators`, vectorised over the data sets (paper: the cftool formulas,
weighted: the mean of m·l, auto: `model.k_estimators.auto_batch`), each checked against `estimate_k`
on the first few data sets. The scatter models are the simulated rig's scenario shapes (additive
a = 0.1 kg, multiplicative b = 0.085, mixed a = 0.07 kg and b = 0.06, read from their configs) and
two sized like the paper's fits (additive a = 0.126 kg, mixed a = b = 0.06). Printed per case and
estimator: the coverage of the 99 % bounds with its 95 % binomial (Wilson) interval, the relative bias,
MSE / CRLB (`model.k_estimators.crlb_k`) and the RMSE relative to k (which compares the designs: the CRLB
differs between them).

    .venv/bin/python studies/estimator_coverage.py [--datasets 100000] [--seed 0]
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scatter_shapes import scenario_shapes

from model.fit import t_quantile
from model.k_estimators import auto_batch, crlb_k, estimate_k

K_TRUE = 0.1615  # kg·m
LEVEL = 0.99
DESIGNS = {  # name: distances [m] of one data set (8 distances x 3 repeats)
    "0.10-0.25 m x 8 x 3": np.repeat(np.linspace(0.10, 0.25, 8), 3),
    "0.03-0.25 m x 8 x 3 (paper)": np.repeat(np.linspace(0.03, 0.25, 8), 3),
}
# Scatter models: (a [kg], b relative). The simulator's three scenario shapes, read from their rig
# configs (scatter_shapes.py), so these numbers and the end-to-end ones are about the same worlds,
# and two sized like the paper's fits instead (RMSE about 0.13 kg on 0.03-0.25 m).
SCATTERS = {
    **{name: (shape.a_kg, shape.b) for name, shape in scenario_shapes().items()},
    "additive-0.126": (0.126, 0.0),
    "mixed-0.06": (0.06, 0.06),
}


def wilson(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval of a binomial proportion."""
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    return centre - half, centre + half


def estimates(distances: np.ndarray, m: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(k, half-width of the 99 % bound) per data set, per estimator."""
    x = 1.0 / distances
    n = x.size
    t = t_quantile(LEVEL, n - 1)
    k_paper = m @ x / (x @ x)
    rmse = np.sqrt(((m - k_paper[:, None] * x) ** 2).sum(axis=1) / (n - 1))
    products = m * distances
    k_weighted = products.mean(axis=1)
    se_weighted = products.std(axis=1, ddof=1) / math.sqrt(n)
    auto = auto_batch(distances, m, LEVEL)
    return {
        "paper": (k_paper, t * rmse / math.sqrt(x @ x)),
        "weighted": (k_weighted, t * se_weighted),
        "auto": (auto.k, auto.t * auto.se),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--datasets", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--chunk", type=int, default=20_000, help="data sets per vectorised batch")
    args = parser.parse_args()
    print(f"k = {K_TRUE} kg·m, {args.datasets} data sets per case, 99 % bounds, seed {args.seed}")
    print(
        f"{'design':<28} {'scatter':<15} {'estimator':<9} {'coverage':>8} {'95 % CI':>17} "
        f"{'bias %':>7} {'MSE/CRLB':>8} {'RMSE %':>7}"
    )
    rng = np.random.default_rng(args.seed)
    for design, distances in DESIGNS.items():
        x = 1.0 / distances
        for scatter, (a, b) in SCATTERS.items():
            sd = np.sqrt(a * a + (b * K_TRUE * x) ** 2)
            covered: dict[str, int] = {}
            sq_error: dict[str, float] = {}
            error: dict[str, float] = {}
            done = 0
            while done < args.datasets:
                size = min(args.chunk, args.datasets - done)
                m = K_TRUE * x + sd * rng.standard_normal((size, x.size))
                results = estimates(distances, m)
                if done == 0:  # the vectorised formulas are the project's estimators
                    for name, (k, half) in results.items():
                        for i in range(3):
                            ref = estimate_k(name, distances.tolist(), m[i].tolist(), None, LEVEL)  # type: ignore[arg-type]
                            assert math.isclose(ref.k, k[i], rel_tol=1e-9), (name, ref.k, k[i])
                            assert math.isclose(ref.k_ci[1] - ref.k, half[i], rel_tol=1e-7), (name, i)
                for name, (k, half) in results.items():
                    covered[name] = covered.get(name, 0) + int(np.sum(np.abs(k - K_TRUE) <= half))
                    sq_error[name] = sq_error.get(name, 0.0) + float(np.sum((k - K_TRUE) ** 2))
                    error[name] = error.get(name, 0.0) + float(np.sum(k - K_TRUE))
                done += size
            bound = crlb_k(distances, K_TRUE, a, b)
            for name in covered:
                lo, hi = wilson(covered[name], done)
                print(
                    f"{design:<28} {scatter:<15} {name:<9} {covered[name] / done:8.4f} "
                    f"[{lo:.4f}, {hi:.4f}] {100 * error[name] / done / K_TRUE:7.3f} "
                    f"{sq_error[name] / done / bound:8.3f} "
                    f"{100 * math.sqrt(sq_error[name] / done) / K_TRUE:7.3f}"
                )


if __name__ == "__main__":
    main()
