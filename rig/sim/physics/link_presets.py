"""Presets of the simulated rig resembling the paper's two links, with every hidden parameter named.

A preset (`SimPreset`) is the single source of truth for the simulated world: the test article's
true joint capacities and geometry, the friction behaviour (per-trial variation, kinetic ratio,
optional torsion-weak joint), the winch drum and line, the bending fixture, and the noise levels of
the simulated sensors. `SimWorld.truth()` reports it as ground truth.

Where the numbers come from (docs/model.md §4 and the paper's text; its Tables I-III were lost):

* **Capacities.** The paper's fits give k = 0.1615 kg·m (link 1, 8 joints) and 0.2627 kg·m
  (link 2, 10 joints), i.e. joint capacities k·g = 1.583 N·m and 2.574 N·m. The joint-estimation
  specimen has exactly that nominal capacity; the link's joints scatter around it with a relative
  standard deviation of 10 % (`JOINT_SPREAD_SD`, drawn from the seed, clipped at ±3 sd), so that a
  prediction from the specimen's fit is off by about 10 % per joint, as in the paper's validation
  (mean percentage error 9.5 % and 12.5 %).
* **Radius R = 0.01 m** for both links (the paper's Table I was lost; 0.01 m is a typical small
  ball joint). R only converts capacity to μs·δ0 and back; it never changes a slip load.
* **Geometry.** Segments of 0.03 m, the acting point 0.03 m beyond the tip joint. The straight link
  lies along the base z axis, configurations bend about y (the x-z plane is horizontal) and the line
  pulls vertically along -y, out of the plane, as in docs/model.md §8 and §9.4. Straight,
  link 1 then slips at its base joint with a base moment of 1.78 N·m and link 2 of 2.83 N·m, close
  to the paper's Table V means (1.77 and 2.79 N·m); this is a plausibility check, not a fit.
* **Joint-estimation distances.** The paper's distances are unknown. 8 distances evenly spaced over
  0.03-0.25 m (link 1) and 10 over 0.035-0.30 m (link 2) give the same spread of slip masses as the
  paper's fits imply (SST = SSE/(1-R²) = 17.65 and 38.7 kg²; these distances give 17.7 and 37.9).
* **Per-trial variation** of each joint's capacity (multiplicative, normal, clipped at ±3 sd) is
  chosen so that a joint-estimation fit on those distances has an RMSE near the paper's 0.126 kg;
  `studies/calibrate_sim_noise.py` measures it (see studies/README.md).
* **Kinetic ratio** 0.8: after a slip the joint turns until its moment is 80 % of the static
  capacity.
* **Winch and line.** Drum radius 0.01 m and a braided line of 5000 N/m, so 1 rad of winch rotation
  adds 50 N. No spring by default (`spring_stiffness_n_per_m` adds one in series): with a soft
  spring, the ~50 N slips at the shortest joint-estimation distances need centimetres of take-up to
  relax, i.e. the specimen turns by tens of degrees per slip and the lever arm itself changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from model.gravity import PAPER_G_M_S2
from model.joint import resolve_constant
from rig.sim.settings import (
    MAX_SCATTER_A_KG,
    SCATTER_SHAPES,
    CapacityScatter,
    LoadCellArtefacts,
    SlipKindMix,
)

PAPER_K_LINK1_KG_M = 0.1615
PAPER_K_LINK2_KG_M = 0.2627
JOINT_SPREAD_SD = 0.10  # relative sd of true joint capacities about the nominal one
PRESET_NAMES = ("link1", "link2")

# Random streams derived from one seed: numpy SeedSequence entropy (seed, stream).
STREAM_ARTICLE = 0  # joint capacities of the preset
STREAM_TRIAL_CAPACITY = 1  # per-trial variation
STREAM_BEND = 2  # placement error of the bending fixture
STREAM_MEASUREMENT = 3  # configuration-source noise
STREAM_SLIP_REPORT = 4  # whether the configuration source names the slipped joint
STREAM_SLIP_KIND = 5  # each trial's slip kind and its parameters
STREAM_LOADCELL_ARTEFACTS = 6  # load-cell spikes, zero wander and the mains hum's phase


def stream_rng(seed: int, stream: int) -> np.random.Generator:
    """An independent generator for one random stream of a seeded simulation."""
    return np.random.default_rng((int(seed), int(stream)))


@dataclass(frozen=True)
class SimPreset:
    """Every parameter of the simulated rig. Angles in rad, lengths in m, forces in N, moments in N·m.

    Friction, beyond the capacities: each trial draws its capacity scatter (`scatter_shape`, with
    a = `scatter_a_kg` and b = `per_trial_capacity_sd`, so that a slip mass m scatters with
    sd(m)² = a² + (b·m)²) and its slip kind from `slip_mix` (`rig.sim.settings.SlipKindMix`: sudden
    drops to `kinetic_ratio`, small drops, creep, stick-slip trains, a neighbouring joint slipping
    first, or no slip before the force limit; each kind's parameters are documented there and in
    protocols/README.md). `loadcell_artefacts` (`rig.sim.settings.LoadCellArtefacts`: drift, zero
    wander, spikes, mains hum, gain creep) is what the simulated load cell adds to the tension;
    `loadcell_noise_n` already includes its `noise_scale`.
    """

    name: str
    seed: int  # seed the joint capacities were drawn with
    # Test article: joint i (1-based) has capacity joint_capacities_nm[i-1].
    joint_capacities_nm: tuple[float, ...]
    specimen_capacity_nm: float  # the single joint used for joint estimation (paper V-A)
    segment_lengths_m: tuple[float, ...]  # p_i = (0, 0, L_i) in {i-1}
    point_m: tuple[float, float, float]  # acting point Q in the tip frame {J}
    direction_w: tuple[float, float, float]  # unit line direction from Q toward the winch, base frame
    joint_radius_m: float
    constant: str  # capacity constant name for μs·δ0 in the truth ('paper' or 'derived')
    g: float
    joint_estimation_distances_m: tuple[float, ...]
    # Friction.
    per_trial_capacity_sd: float  # relative sd of each joint's capacity from trial to trial
    kinetic_ratio: float  # kinetic / static capacity, in (0, 1)
    slip_rate_rad_s: float  # how fast a slipping joint turns (math.inf: within one substep)
    torsion_weak_joint: int | None = None  # 1-based; None: every joint isotropic (the paper's assumption)
    torsion_ratio: float = 0.5  # α: the weak joint's torsion capacity is α·capacity
    # Winch, line and spring (winch angle increasing = reeling in).
    drum_radius_m: float = 0.01
    line_stiffness_n_per_m: float = 5000.0
    spring_stiffness_n_per_m: float | None = None  # None: no spring in the line
    # Reel-in from the winch's starting angle before the line is taut; negative: the line starts
    # stretched by that much drum travel (loaded, `simulation.initial_tension_n`).
    winch_slack_rad: float = 0.5
    # Bending: the forks' contact stiffness (rig/sim/physics/forks.py), and a person's placement error.
    fork_contact_stiffness_n_per_m: float = 1.0e5
    sigma_bend_rad: float = math.radians(1.0)  # per-joint placement error when a person bends by hand
    # Sensors.
    sigma_meas_rad: float = math.radians(0.4)  # configuration measurement noise per joint angle
    slipped_joint_report_probability: float = 0.8  # chance the configuration source names the joint
    loadcell_noise_n: float = 0.005  # RMS, for the load-cell emulator (its default); the world is noise-free
    # Slip kinds, scatter shape and load-cell artefacts (defaults: the paper-like world of before).
    slip_mix: SlipKindMix = field(default_factory=SlipKindMix)
    scatter_shape: str = "multiplicative"
    scatter_a_kg: float = 0.0  # additive sd of the slip mass [kg] (shapes additive and mixed)
    loadcell_artefacts: LoadCellArtefacts = field(default_factory=LoadCellArtefacts)

    def __post_init__(self) -> None:
        """Check shapes and ranges; a `ValueError` names the field and what is allowed."""
        joints = len(self.joint_capacities_nm)
        if joints < 1 or len(self.segment_lengths_m) != joints:
            raise ValueError(
                f"preset {self.name}: {joints} capacities and {len(self.segment_lengths_m)} segment "
                "lengths; allowed: the same number, at least 1"
            )
        positive = {
            "joint_capacities_nm": min(self.joint_capacities_nm),
            "specimen_capacity_nm": self.specimen_capacity_nm,
            "segment_lengths_m": min(self.segment_lengths_m),
            "joint_radius_m": self.joint_radius_m,
            "g": self.g,
            "slip_rate_rad_s": self.slip_rate_rad_s,
            "torsion_ratio": self.torsion_ratio,
            "drum_radius_m": self.drum_radius_m,
            "line_stiffness_n_per_m": self.line_stiffness_n_per_m,
            "fork_contact_stiffness_n_per_m": self.fork_contact_stiffness_n_per_m,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ValueError(f"preset {self.name}: {name} = {value!r}; allowed: > 0")
        if self.spring_stiffness_n_per_m is not None and not self.spring_stiffness_n_per_m > 0:
            raise ValueError(f"preset {self.name}: spring_stiffness_n_per_m must be > 0 or None")
        if not 0 < self.kinetic_ratio < 1:
            raise ValueError(f"preset {self.name}: kinetic_ratio = {self.kinetic_ratio}; allowed: (0, 1)")
        if not 0 <= self.per_trial_capacity_sd < 1:
            raise ValueError(
                f"preset {self.name}: per_trial_capacity_sd = {self.per_trial_capacity_sd}; allowed: [0, 1)"
            )
        for name in ("sigma_bend_rad", "sigma_meas_rad", "loadcell_noise_n"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"preset {self.name}: {name} must be >= 0")
        if not math.isfinite(self.winch_slack_rad):
            raise ValueError(f"preset {self.name}: winch_slack_rad must be finite")
        if not 0 <= self.slipped_joint_report_probability <= 1:
            raise ValueError(f"preset {self.name}: slipped_joint_report_probability allowed: [0, 1]")
        if self.torsion_weak_joint is not None and not 1 <= self.torsion_weak_joint <= joints:
            raise ValueError(
                f"preset {self.name}: torsion_weak_joint = {self.torsion_weak_joint}; allowed: 1..{joints}"
            )
        if self.torsion_ratio > 1:
            raise ValueError(f"preset {self.name}: torsion_ratio = {self.torsion_ratio}; allowed: (0, 1]")
        if math.hypot(*self.direction_w) == 0:
            raise ValueError(f"preset {self.name}: direction_w is zero; allowed: a non-zero 3-vector")
        if not self.joint_estimation_distances_m or min(self.joint_estimation_distances_m) <= 0:
            raise ValueError(f"preset {self.name}: joint_estimation_distances_m must be > 0")
        resolve_constant(self.constant)
        if self.scatter_shape not in SCATTER_SHAPES:
            allowed = ", ".join(SCATTER_SHAPES)
            raise ValueError(
                f"preset {self.name}: scatter_shape = {self.scatter_shape!r}; allowed: {allowed}"
            )
        if not 0 <= self.scatter_a_kg <= MAX_SCATTER_A_KG:
            raise ValueError(
                f"preset {self.name}: scatter_a_kg = {self.scatter_a_kg}; allowed: 0-{MAX_SCATTER_A_KG:g}"
            )

    @property
    def joint_count(self) -> int:
        """Number of joints J of the link."""
        return len(self.joint_capacities_nm)

    @property
    def effective_line_stiffness_n_per_m(self) -> float:
        """Line and spring in series."""
        if self.spring_stiffness_n_per_m is None:
            return self.line_stiffness_n_per_m
        return 1.0 / (1.0 / self.line_stiffness_n_per_m + 1.0 / self.spring_stiffness_n_per_m)

    @property
    def unit_direction_w(self) -> tuple[float, float, float]:
        """`direction_w` normalised."""
        norm = math.hypot(*self.direction_w)
        x, y, z = self.direction_w
        return (x / norm, y / norm, z / norm)


@dataclass(frozen=True)
class _LinkSpec:
    k_kg_m: float
    joints: int
    segment_m: float
    distances_m: tuple[float, ...]
    per_trial_capacity_sd: float


_LINKS = {
    "link1": _LinkSpec(
        k_kg_m=PAPER_K_LINK1_KG_M,
        joints=8,
        segment_m=0.03,
        distances_m=tuple(float(x) for x in np.linspace(0.03, 0.25, 8)),
        per_trial_capacity_sd=0.085,
    ),
    "link2": _LinkSpec(
        k_kg_m=PAPER_K_LINK2_KG_M,
        joints=10,
        segment_m=0.03,
        distances_m=tuple(float(x) for x in np.linspace(0.035, 0.30, 10)),
        per_trial_capacity_sd=0.059,
    ),
}


def make_preset(
    name: str,
    seed: int = 0,
    *,
    noise_scale: float = 1.0,
    torsion_weak_joint: int | None = None,
    segment_lengths_m: tuple[float, ...] | None = None,
    point_m: tuple[float, float, float] | None = None,
    direction_w: tuple[float, float, float] | None = None,
    joint_radius_m: float | None = None,
    drum_radius_m: float | None = None,
    g: float | None = None,
    slip_mix: SlipKindMix | None = None,
    scatter: CapacityScatter | None = None,
    loadcell_artefacts: LoadCellArtefacts | None = None,
) -> SimPreset:
    """Build preset `name` ('link1' or 'link2'), drawing its joint capacities from `seed`.

    `noise_scale` multiplies every noise level (per-trial variation, placement and measurement
    error, load-cell noise). The geometry arguments override the preset's (a rig config's article
    section); `segment_lengths_m` must keep the preset's joint count. `slip_mix`, `scatter` and
    `loadcell_artefacts` come from the rig config's `simulation:` section (defaults: sudden slips,
    multiplicative scatter with the preset's sd, no artefacts); `noise_scale` scales the scatter's
    a and b too, and the artefacts' `noise_scale` the load cell's white noise.
    """
    if name not in _LINKS:
        raise ValueError(f"unknown simulation preset {name!r}; allowed: {', '.join(PRESET_NAMES)}")
    if not (math.isfinite(noise_scale) and noise_scale >= 0):
        raise ValueError(f"noise_scale = {noise_scale!r}; allowed: finite and >= 0")
    spec = _LINKS[name]
    g_value = PAPER_G_M_S2 if g is None else float(g)
    nominal_nm = spec.k_kg_m * PAPER_G_M_S2  # the paper's capacity, whatever g the rig uses
    spread = stream_rng(seed, STREAM_ARTICLE).standard_normal(spec.joints)
    factors = 1.0 + JOINT_SPREAD_SD * np.clip(spread, -3.0, 3.0)
    lengths = (spec.segment_m,) * spec.joints if segment_lengths_m is None else tuple(segment_lengths_m)
    if len(lengths) != spec.joints:
        raise ValueError(
            f"preset {name} has {spec.joints} joints but {len(lengths)} segment lengths were given; "
            f"allowed: exactly {spec.joints}"
        )
    preset = SimPreset(
        name=name,
        seed=int(seed),
        joint_capacities_nm=tuple(float(nominal_nm * f) for f in factors),
        specimen_capacity_nm=float(nominal_nm),
        segment_lengths_m=tuple(float(x) for x in lengths),
        point_m=(0.0, 0.0, spec.segment_m) if point_m is None else tuple(float(x) for x in point_m),  # type: ignore[arg-type]
        direction_w=(0.0, -1.0, 0.0) if direction_w is None else tuple(float(x) for x in direction_w),  # type: ignore[arg-type]
        joint_radius_m=0.01 if joint_radius_m is None else float(joint_radius_m),
        constant="paper",
        g=g_value,
        joint_estimation_distances_m=spec.distances_m,
        per_trial_capacity_sd=spec.per_trial_capacity_sd,
        kinetic_ratio=0.8,
        slip_rate_rad_s=5.0,
        torsion_weak_joint=torsion_weak_joint,
        drum_radius_m=0.01 if drum_radius_m is None else float(drum_radius_m),
    )
    scatter = scatter or CapacityScatter()
    artefacts = loadcell_artefacts or LoadCellArtefacts()
    preset = replace(
        preset,
        slip_mix=slip_mix or SlipKindMix(),
        scatter_shape=scatter.shape,
        scatter_a_kg=scatter.a_kg,
        per_trial_capacity_sd=0.0
        if scatter.shape == "additive"
        else (preset.per_trial_capacity_sd if scatter.b is None else scatter.b),
        loadcell_artefacts=artefacts,
    )
    if artefacts.noise_scale != 1.0:
        preset = replace(preset, loadcell_noise_n=preset.loadcell_noise_n * artefacts.noise_scale)
    return scale_noise(preset, noise_scale)


def scale_noise(preset: SimPreset, noise_scale: float) -> SimPreset:
    """The same preset with every noise level multiplied by `noise_scale`."""
    if noise_scale == 1.0:
        return preset
    return replace(
        preset,
        per_trial_capacity_sd=preset.per_trial_capacity_sd * noise_scale,
        scatter_a_kg=preset.scatter_a_kg * noise_scale,
        sigma_bend_rad=preset.sigma_bend_rad * noise_scale,
        sigma_meas_rad=preset.sigma_meas_rad * noise_scale,
        loadcell_noise_n=preset.loadcell_noise_n * noise_scale,
    )
