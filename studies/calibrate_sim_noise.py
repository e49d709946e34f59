"""Measure what the simulated rig's noise does to a joint-estimation fit, against the paper's figures.

For each preset (link1, link2) this simulates many joint-estimation data sets with `SimWorld`
directly (no device emulators): at each of the preset's distances the single-joint specimen is
loaded by an idealised winch ramp from slack until it slips; the tension is sampled at 1 kHz from
`SimWorld.tension_at` with the preset's load-cell noise added, and the slip load is what the
project's own detector (`model.slip_detector.detect_slips`, default parameters) reports as the
peak. Each data set is fitted with `model.fit.fit_inverse_distance` (99 % bounds).

Printed per preset: the RMSE distribution (median, IQR) against the paper's 0.126 kg, R² and SST
against the paper's, the median fitted k against the true k (the specimen's capacity / g), and the
coverage of the 99 % bounds over the true k.

    .venv/bin/python studies/calibrate_sim_noise.py [--datasets 300] [--seed 0] [--rate 4.0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from model.fit import fit_inverse_distance
from model.slip_detector import DetectorParams, detect_slips
from rig.sim.physics.link_presets import PRESET_NAMES, make_preset
from rig.sim.physics.world import SimWorld

PAPER = {  # docs/model.md §4: k, SSE, R², RMSE
    "link1": {"k": 0.1615, "sse": 0.1112, "r2": 0.9937, "rmse": 0.1261},
    "link2": {"k": 0.2627, "sse": 0.1432, "r2": 0.9963, "rmse": 0.1261},
}
SAMPLE_NS = 1_000_000  # 1 kHz load cell
STEP_NS = 100_000_000


class IdealWinch:
    """A winch that turns at a constant rate, whatever the line's torque."""

    def __init__(self) -> None:
        self.present_position_rad = 0.0
        self.external_torque_nm = 0.0
        self.rate_rad_s = 0.0
        self.last_ns = 0

    def step(self, t_ns: int) -> None:
        self.present_position_rad += self.rate_rad_s * (t_ns - self.last_ns) * 1e-9
        self.last_ns = t_ns


def one_slip_mass_kg(
    world: SimWorld, winch: IdealWinch, distance_m: float, rate_rad_s: float, rng: np.random.Generator
) -> float:
    """One joint-estimation trial: ramp from slack to the first slip, detect it in noisy samples."""
    world.place_hook(distance_m)
    winch.present_position_rad = world.taut_winch_angle_rad() - 0.05
    winch.rate_rad_s = rate_rad_s
    winch.last_ns = world.now_ns
    start_ns = world.now_ns
    slips_before = len(world.slips)
    while len(world.slips) == slips_before:
        world.advance_to(world.now_ns + STEP_NS)
        if world.now_ns - start_ns > 120_000_000_000:
            raise RuntimeError(f"no slip within 120 s at {distance_m} m")
    onset_ns = world.slips[slips_before].onset.onset_ns
    world.advance_to(onset_ns + 60_000_000)  # let the drop complete
    winch.rate_rad_s = 0.0
    first_ns = max(start_ns, onset_ns - 1_500_000_000) // SAMPLE_NS * SAMPLE_NS + SAMPLE_NS
    times = list(range(first_ns, onset_ns + 50_000_000, SAMPLE_NS))
    noise = rng.normal(0.0, world.preset.loadcell_noise_n, len(times))
    forces = [world.tension_at(t) + e for t, e in zip(times, noise, strict=True)]
    events = detect_slips(DetectorParams(), times, forces)
    if not events:
        raise RuntimeError(f"the detector missed the slip at {distance_m} m")
    return events[0].peak_force_n / world.preset.g


def calibrate(name: str, datasets: int, seed: int, rate_rad_s: float) -> dict[str, float]:
    rmse, r2, sst, k, covered = [], [], [], [], 0
    k_true = 0.0
    for i in range(datasets):
        preset = make_preset(name, seed=seed + i)
        k_true = preset.specimen_capacity_nm / preset.g
        winch = IdealWinch()
        world = SimWorld(preset, winch, step_devices=winch.step, seed=seed + i)
        rng = np.random.default_rng((seed + i, 99))
        distances = preset.joint_estimation_distances_m
        masses = [one_slip_mass_kg(world, winch, d, rate_rad_s, rng) for d in distances]
        fit = fit_inverse_distance(distances, masses, level=0.99)
        rmse.append(fit.rmse)
        r2.append(fit.r2)
        sst.append(fit.sst)
        k.append(fit.k)
        covered += fit.k_ci[0] <= k_true <= fit.k_ci[1]
    q = np.percentile(rmse, [25, 50, 75])
    return {
        "rmse_q25": q[0],
        "rmse_median": q[1],
        "rmse_q75": q[2],
        "r2_median": float(np.median(r2)),
        "sst_median": float(np.median(sst)),
        "k_median": float(np.median(k)),
        "k_true": k_true,
        "coverage_99": covered / datasets,
        "per_trial_capacity_sd": make_preset(name, seed=seed).per_trial_capacity_sd,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rate", type=float, default=4.0, help="winch ramp [rad/s]")
    parser.add_argument("--preset", choices=PRESET_NAMES, action="append")
    args = parser.parse_args()
    for name in args.preset or PRESET_NAMES:
        t0 = time.perf_counter()
        r = calibrate(name, args.datasets, args.seed, args.rate)
        paper = PAPER[name]
        print(f"{name}: {args.datasets} data sets, per-trial capacity sd {r['per_trial_capacity_sd']:.3f}")
        print(
            f"  RMSE median {r['rmse_median']:.4f} kg, IQR {r['rmse_q25']:.4f}-{r['rmse_q75']:.4f} kg"
            f"   (paper {paper['rmse']:.4f} kg)"
        )
        print(f"  R² median {r['r2_median']:.4f} (paper {paper['r2']:.4f})", end="")
        print(f"   SST median {r['sst_median']:.2f} kg² (paper {paper['sse'] / (1 - paper['r2']):.2f} kg²)")
        print(
            f"  k median {r['k_median']:.4f} kg·m, true {r['k_true']:.4f} kg·m (paper fit {paper['k']:.4f})"
        )
        print(f"  99 % bounds cover the true k in {100 * r['coverage_99']:.1f} % of data sets")
        print(f"  ({time.perf_counter() - t0:.1f} s wall)")


if __name__ == "__main__":
    main()
