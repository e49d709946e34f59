"""Cost of the exact O(1) online fit vs refitting all data with numpy after every trial; detector step cost.

Run: .venv/bin/python benchmarks/bench_online_fit.py
"""

import argparse
import math
import time

import numpy as np
from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from model.fit import t_quantile
from model.online_fit import online_fit_estimate, online_fit_init, online_fit_update
from model.slip_detector import DetectorParams, detect_slips


def numpy_refit(x, m, level=0.99):
    (k,), *_ = np.linalg.lstsq(x[:, None], m, rcond=None)
    r = m - k * x
    sse = float(r @ r)
    dfe = len(m) - 1
    se = math.sqrt(sse / dfe) / math.sqrt(float(x @ x))
    t = t_quantile(level, dfe)  # the same cached quantile as the online fit: compare the arithmetic
    return k, (k - t * se, k + t * se)


def time_online(distances, masses):
    start = time.perf_counter()
    state = online_fit_init()
    for d, m in zip(distances, masses, strict=True):
        state = online_fit_update(state, d, m)
        online_fit_estimate(state)
    return time.perf_counter() - start


def time_numpy(distances, masses):
    x_all = 1.0 / np.asarray(distances)
    m_all = np.asarray(masses)
    start = time.perf_counter()
    for i in range(1, len(masses) + 1):
        if i >= 2:
            numpy_refit(x_all[:i], m_all[:i])
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    sizes, repeats = ((10, 100), 1) if args.smoke else ((10, 100, 1000, 3000), 3)
    rng = np.random.default_rng(0)
    print(
        "online fit: update + estimate after every trial, whole sequence "
        f"(best of {repeats}; t quantiles cached)"
    )
    print(f"{'trials':>7} {'online ms':>10} {'numpy ms':>10} {'online/numpy':>13} {'online us/trial':>16}")
    for n in sizes:
        for dfe in range(1, n):  # warm the shared t-quantile cache: scipy's t.ppf is not what is compared
            t_quantile(0.99, dfe)
        distances = rng.uniform(0.03, 0.5, n)
        masses = 0.16 / distances + rng.normal(0, 0.05, n)
        online = min(time_online(distances, masses) for _ in range(repeats))
        refit = min(time_numpy(distances, masses) for _ in range(repeats))
        ratio = online / refit
        print(f"{n:>7} {online * 1e3:>10.2f} {refit * 1e3:>10.2f} {ratio:>13.2f} {online / n * 1e6:>16.1f}")

    print()
    print("slip detector: detect_slips over a 1 kHz trace (ramp 3 s, slip, hold, unload), per sample")
    t_s = np.arange(0, 4.52, 0.001)
    force = np.interp(t_s, [0, 3, 3.02, 3.52, 4.02], [0, 15, 9, 9, 0]) + rng.normal(0, 0.02, t_s.size)
    times_ns = [round(t * 1e9) for t in t_s]
    forces = force.tolist()
    for name, params in (
        ("drop only", DetectorParams()),
        (
            "drop+slope(20 ms)+cusum",
            DetectorParams(slope_n_per_s=50.0, slope_window_s=0.02, cusum_threshold_n=1.0),
        ),
    ):
        seconds = []
        for _ in range(repeats):
            start = time.perf_counter()
            events = detect_slips(params, times_ns, forces)
            seconds.append(time.perf_counter() - start)
        assert len(events) == 1, events
        per_sample_us = min(seconds) / len(forces) * 1e6
        share = per_sample_us / 1000 * 100
        print(f"  {name:<26} {per_sample_us:6.2f} us/sample = {share:5.2f} % of a 1 kHz sample period")


if __name__ == "__main__":
    main()
