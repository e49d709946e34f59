"""Throughput of the vectorised chain statics (model/chain.py) against a per-configuration Python loop.

A 10-joint planar link in 100,000 random configurations. Figures are joint evaluations per second
(configurations x joints / s), best of several repetitions, on one core. The loop calls the same
public functions once per configuration; it is timed on a subset and scaled (the output says so).

Run: .venv/bin/python benchmarks/bench_chain.py [--configs N] [--loop-configs N]
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402 (thread limits must be set before numpy loads)
from smoke_mode import SMOKE_HELP  # noqa: E402 (benchmarks/ is the script's directory)

from model.chain import joint_moment_norms, planar_transforms, predict_slip  # noqa: E402

N_JOINTS = 10


def best_of(repeats, fn):
    times = []
    result = None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return min(times), result


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--configs", type=int, default=100_000)
    parser.add_argument("--loop-configs", type=int, default=2_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.configs, args.loop_configs, args.repeats = 2_000, 200, 1

    rng = np.random.default_rng(12345)
    angles = rng.uniform(-0.6, 0.6, (args.configs, N_JOINTS))
    lengths = np.full(N_JOINTS, 0.03)
    capacities = rng.uniform(0.5, 2.5, N_JOINTS)
    point = np.array([0.0, 0.0, 0.03])
    force = np.array([0.0, -9.8, 0.0])
    direction = np.array([0.0, 0.0, -1.0])
    joint_evals = args.configs * N_JOINTS

    t_build, transforms = best_of(args.repeats, lambda: planar_transforms(angles, lengths))
    t_norms, norms = best_of(args.repeats, lambda: joint_moment_norms(transforms, point, force))
    t_slip, slip = best_of(args.repeats, lambda: predict_slip(transforms, capacities, point, direction))
    t_full, _ = best_of(
        args.repeats, lambda: predict_slip(planar_transforms(angles, lengths), capacities, point, direction)
    )

    subset = min(args.loop_configs, args.configs)

    def loop_norms():
        return np.stack([joint_moment_norms(transforms[k], point, force) for k in range(subset)])

    def loop_slip():
        return [predict_slip(transforms[k], capacities, point, direction).slip_force_n for k in range(subset)]

    t_loop_norms, loop_result = best_of(args.repeats, loop_norms)
    t_loop_slip, loop_slip_result = best_of(args.repeats, loop_slip)
    # Same numbers either way (guards against timing a broken path).
    np.testing.assert_allclose(loop_result, norms[:subset], rtol=1e-12)
    np.testing.assert_allclose(
        np.array(loop_slip_result, dtype=float), slip.slip_force_n[:subset], rtol=1e-12
    )
    scale = args.configs / subset

    def rate(seconds):
        return joint_evals / seconds

    print(
        f"bench_chain: {N_JOINTS}-joint planar link, {args.configs:,} configurations, best of {args.repeats}"
    )
    print(f"python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}, 1 thread")
    print(f"  planar_transforms        {t_build * 1e3:9.1f} ms   {rate(t_build):14,.0f} joint evals/s")
    print(f"  joint_moment_norms       {t_norms * 1e3:9.1f} ms   {rate(t_norms):14,.0f} joint evals/s")
    print(f"  predict_slip             {t_slip * 1e3:9.1f} ms   {rate(t_slip):14,.0f} joint evals/s")
    print(f"  transforms+predict_slip  {t_full * 1e3:9.1f} ms   {rate(t_full):14,.0f} joint evals/s")
    print(f"per-configuration loop over the same functions: timed on {subset:,} configurations, x{scale:g}")
    for name, loop_seconds, vector_seconds in (
        ("joint_moment_norms loop", t_loop_norms * scale, t_norms),
        ("predict_slip loop", t_loop_slip * scale, t_slip),
    ):
        print(
            f"  {name:<24} {loop_seconds * 1e3:9.1f} ms   {rate(loop_seconds):14,.0f} joint evals/s"
            f"   vectorised/loop = {loop_seconds / vector_seconds:,.0f}x"
        )


if __name__ == "__main__":
    main()
