"""Cost of refitting k after every trial online, per estimator, against the paper's online fit.

A run refits after every trial: for a sequence of n trials that is n − 1 fits of 2, 3, ..., n points.
Timed side by side in one process (best of `--rounds`), on the paper's design (0.03-0.25 m, 8 x 3,
shuffled, proportional scatter):

* paper: the exact O(1) online fit (`model.online_fit`), update + estimate after every trial;
* weighted, auto: `model.k_estimators.estimate_k` of all points so far after every trial;
* auto with censoring: the same with every fifth trial a no-slip lower bound (Tobit likelihood).

Run: .venv/bin/python benchmarks/bench_estimators.py [--trials 24 96] [--rounds 3]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from model.fit import t_quantile
from model.k_estimators import estimate_k
from model.online_fit import online_fit_estimate, online_fit_init, online_fit_update


def sequence(trials: int, seed: int = 0) -> tuple[list[float], list[float], list[bool]]:
    """Shuffled distances of the paper's design (repeated to `trials`), masses, censoring flags."""
    rng = np.random.default_rng(seed)
    distances = np.resize(np.repeat(np.linspace(0.03, 0.25, 8), 3), trials)
    rng.shuffle(distances)
    masses = 0.1615 / distances * (1 + 0.085 * rng.standard_normal(trials))
    censored = [i % 5 == 4 for i in range(trials)]
    return distances.tolist(), masses.tolist(), censored


def time_paper(d: list[float], m: list[float], _: list[bool]) -> float:
    start = time.perf_counter()
    state = online_fit_init()
    for di, mi in zip(d, m, strict=True):
        state = online_fit_update(state, di, mi)
        online_fit_estimate(state)
    return time.perf_counter() - start


def refit_every_trial(
    name: str, with_censoring: bool
) -> Callable[[list[float], list[float], list[bool]], float]:
    def run(d: list[float], m: list[float], censored: list[bool]) -> float:
        flags = censored if with_censoring else [False] * len(m)
        start = time.perf_counter()
        for i in range(2, len(m) + 1):
            if flags[:i].count(False) >= 2:
                estimate_k(name, d[:i], m[:i], flags[:i])  # type: ignore[arg-type]
        return time.perf_counter() - start

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--trials", type=int, nargs="+", default=[24, 96])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.trials, args.rounds = [24], 1
    for dfe in range(1, max(args.trials) + 1):  # the t quantiles are cached for every estimator alike
        t_quantile(0.99, dfe)
    estimate_k("auto", [0.1, 0.2, 0.3], [1.0, 0.5, 0.34], [False, False, True])  # import scipy once
    paths = {
        "paper (online, exact)": time_paper,
        "weighted": refit_every_trial("weighted", False),
        "auto": refit_every_trial("auto", False),
        "auto, 1 in 5 censored": refit_every_trial("auto", True),
    }
    print("refit after every trial: whole sequence, best of", args.rounds)
    print(f"{'trials':>6}  {'estimator':<24} {'total ms':>9} {'ms/trial':>9} {'x paper':>8}")
    for n in args.trials:
        data = sequence(n)
        best = {name: min(path(*data) for _ in range(args.rounds)) for name, path in paths.items()}
        paper = best["paper (online, exact)"]
        for name, seconds in best.items():
            print(f"{n:>6}  {name:<24} {seconds * 1e3:9.2f} {seconds / n * 1e3:9.3f} {seconds / paper:8.1f}")


if __name__ == "__main__":
    main()
