"""What a simulated rig knows and a real one cannot, as typed records: the ground truth of a run.

The simulated world (`rig.sim.physics.world.SimWorld.truth`) makes these records; the simulated
rig's `SimGroundTruth` (rig/sim/simulated_rig.py), handed to the runner beside the session
(`rig.runner.rig_to_run.GroundTruth`), adds the rig's state at that moment. Readers (`rig study`,
the CLI, tests) use the fields; the runner only passes the snapshot on and calls `to_json` where the
truth leaves the process: the log's `sim_truth` metadata (`RunTruth.to_json()`, with every trial)
and the `truth` object of `rig run --json` (`RunTruth.to_json(with_trials=False)`). The JSON
layout is docs/formats.md's; its keys and their order are fixed by these methods.

They are the simulator's: no layer below it (the session contract, the runner, the input files)
imports them (an import contract says so).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from rig.sim.kinds import ArticleSetup, SlipKind
from rig.sim.settings import LoadCellArtefacts, SlipKindMix
from rig.vocabulary import TrialKind

SCATTER_SD_FORMULA = "sqrt(a^2 + (b m)^2)"
TORSION_CRITERION = "sqrt((|N_bend|/cap)^2 + (N_torsion/(torsion_ratio*cap))^2) > 1"
TORSION_AXIS = "z axis of the joint's own frame {i} (the axis of component i)"
ESTIMATED_JOINT = 1  # the joint whose k a joint-estimation run estimates (the specimen is the link's first)


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


@dataclass(frozen=True)
class SlipPlan:
    """The slip kind one trial drew and its parameters (None where the kind has none)."""

    kind: SlipKind
    drop_fraction: float | None = None  # small_drop, stick_slip (each drop), other_joint
    creep_duration_s: float | None = None
    creep_drop_fraction: float | None = None
    train_drops: int | None = None
    dwells_s: tuple[float, ...] = ()  # stick_slip: the dwell before each later drop
    other_joint: int | None = None  # the neighbouring joint (1-based, of the link) that slips
    other_load_n: float | None = None  # the tension at which it slips

    def to_json(self) -> dict[str, Any]:
        """JSON-serialisable copy (an infinite other-joint load becomes None)."""
        out = asdict(self)
        out["dwells_s"] = list(self.dwells_s)
        if self.other_load_n is not None and not math.isfinite(self.other_load_n):
            out["other_load_n"] = None
        return out


@dataclass(frozen=True, kw_only=True)
class SlipTruth:
    """One true slip event: when, which joint (1-based), the tension it happened at, how it ended.

    `joint` is the article's joint (the specimen has one, joint 1); `moved_joint` is the link joint
    that moved, which the configuration source names. `onset_ns`/`end_ns` are on the world's
    monotonic clock, `onset_time_ns` on the run clock (the load-cell samples' clock);
    `peak_tension_n` is the slip load. `end_ns` is None for a slip still under way.

    This is the one definition of a slip's fields: the simulator's `SlipRecord`
    (`rig.sim.physics.slips`) holds the slip's onset as one of these, with the three fields that
    change while it is under way (`end_ns`, `tension_after_n`, `rotation_rad`) at their defaults, and
    `dataclasses.replace`s them when it is read. The field order is the JSON's (`to_json`).
    """

    trial_index: int | None
    setup: ArticleSetup
    joint: int
    onset_ns: int
    peak_tension_n: float  # recorded tension at the onset substep (the maximum before the drop)
    threshold_n: float  # the exact static slip load of the configuration at onset
    end_ns: int | None = None
    tension_after_n: float | None = None
    rotation_rad: float = 0.0
    kind: SlipKind
    moved_joint: int
    onset_time_ns: int | None

    def to_json(self) -> dict[str, Any]:
        """JSON-serialisable copy."""
        return asdict(self)

    def event_json(self, run_clock_offset_ns: int) -> dict[str, Any]:
        """The slip as one of its trial's `slip_events` (times on the run clock)."""
        return {
            "onset_time_ns": self.onset_time_ns,
            "kind": self.kind,
            "load_n": self.peak_tension_n,
            "joint": self.moved_joint,
            "end_time_ns": None if self.end_ns is None else self.end_ns + run_clock_offset_ns,
            "tension_after_n": self.tension_after_n,
        }


@dataclass(frozen=True)
class TrialTruth:
    """What was true for one trial: its capacities, its slip kind and the exact slip load at its start."""

    index: int  # 1-based, in loading order (a run's trials in order: each loads the line once)
    kind: TrialKind
    distance_m: float | None
    specimen_joint: int | None  # joint estimation: the link joint used as the specimen (None: nominal)
    start_ns: int
    capacities_nm: tuple[float, ...]  # of the active setup (one entry for the specimen)
    capacity_factors: tuple[float, ...]
    slip_force_n: float  # static slip load of the configuration as the loading began (inf: cannot slip)
    slip_mass_kg: float
    first_slip_joint: int  # 1-based, 0 if nothing can slip
    slip: SlipPlan = SlipPlan(SlipKind.SUDDEN)
    capacity_relative_sds: tuple[float, ...] = ()  # s of each capacity factor 1 + s·z

    def to_json(self) -> dict[str, Any]:
        """JSON-serialisable copy (an infinite slip load becomes None)."""
        return {
            "index": self.index,
            "kind": self.kind,
            "distance_m": self.distance_m,
            "specimen_joint": self.specimen_joint,
            "start_ns": self.start_ns,
            "capacities_nm": list(self.capacities_nm),
            "capacity_factors": list(self.capacity_factors),
            "slip_force_n": _finite_or_none(self.slip_force_n),
            "slip_mass_kg": _finite_or_none(self.slip_mass_kg),
            "first_slip_joint": self.first_slip_joint,
            "slip": self.slip.to_json(),
            "capacity_relative_sds": list(self.capacity_relative_sds),
            "slip_kind": self.slip.kind,
        }


@dataclass(frozen=True)
class CapacityTruth:
    """A joint's true mean capacity and the k and μs·δ0 it gives."""

    capacity_nm: float
    k_kg_m: float
    mu_delta0_pa: float

    def to_json(self) -> dict[str, float]:
        """JSON-serialisable copy."""
        return {"capacity_nm": self.capacity_nm, "k_kg_m": self.k_kg_m, "mu_delta0_pa": self.mu_delta0_pa}


@dataclass(frozen=True)
class NoiseTruth:
    """The noise levels of the simulated world and its sensors."""

    per_trial_capacity_sd: float
    loadcell_noise_n: float
    sigma_bend_rad: float
    sigma_meas_rad: float
    slipped_joint_report_probability: float


@dataclass(frozen=True)
class ScatterTruth:
    """The trial-to-trial scatter of a slip mass m: sd(m)² = a² + (b·m)²."""

    shape: str
    a_kg: float
    b: float

    def to_json(self) -> dict[str, Any]:
        """JSON-serialisable copy with the formula."""
        return {"shape": self.shape, "a_kg": self.a_kg, "b": self.b, "sd_m": SCATTER_SD_FORMULA}


@dataclass(frozen=True)
class GeometryTruth:
    """The link's geometry, the line's direction and the joint-estimation distances."""

    segment_lengths_m: tuple[float, ...]
    point_m: tuple[float, ...]
    direction_w: tuple[float, ...]
    joint_estimation_distances_m: tuple[float, ...]


@dataclass(frozen=True)
class LineTruth:
    """The winch drum and the line (with its spring, if any)."""

    drum_radius_m: float
    line_stiffness_n_per_m: float
    spring_stiffness_n_per_m: float | None
    effective_stiffness_n_per_m: float
    winch_slack_rad: float


@dataclass(frozen=True)
class WorldTruth:
    """Everything the simulated world was made with, and (when taken with them) its trials and slips."""

    preset: str
    seed: int
    article_seed: int
    g: float
    constant_name: str
    constant_c: float
    joint_radius_m: float
    joints: tuple[CapacityTruth, ...]  # joint i (1-based) is joints[i - 1]
    specimen: CapacityTruth
    noise: NoiseTruth
    kinetic_ratio: float
    scatter: ScatterTruth
    slip_mix: SlipKindMix
    loadcell_artefacts: LoadCellArtefacts
    run_clock_offset_ns: int
    slip_rate_rad_s: float  # math.inf: within one substep
    torsion_weak_joint: int | None
    torsion_ratio: float
    geometry: GeometryTruth
    line: LineTruth
    substep_ns: int
    trials: tuple[TrialTruth, ...] = ()
    slips: tuple[SlipTruth, ...] = ()

    def to_json(self, *, with_trials: bool = True) -> dict[str, Any]:
        """JSON-serialisable copy; `with_trials` adds every trial's draws and slip events and the slips."""
        out: dict[str, Any] = {
            "preset": self.preset,
            "seed": self.seed,
            "article_seed": self.article_seed,
            "g": self.g,
            "constant": {"name": self.constant_name, "c": self.constant_c},
            "joint_radius_m": self.joint_radius_m,
            "joints": [{"joint": i + 1, **j.to_json()} for i, j in enumerate(self.joints)],
            "specimen": self.specimen.to_json(),
            "noise": asdict(self.noise),
            "kinetic_ratio": self.kinetic_ratio,
            "scatter": self.scatter.to_json(),
            "slip_mix": _slip_mix_json(self.slip_mix),
            "loadcell_artefacts": asdict(self.loadcell_artefacts),
            "run_clock_offset_ns": self.run_clock_offset_ns,
            "slip_rate_rad_s": _finite_or_none(self.slip_rate_rad_s),
            "torsion": None
            if self.torsion_weak_joint is None
            else {
                "joint": self.torsion_weak_joint,
                "torsion_ratio": self.torsion_ratio,
                "axis": TORSION_AXIS,
                "criterion": TORSION_CRITERION,
            },
            "geometry": {k: list(v) for k, v in asdict(self.geometry).items()},
            "line": asdict(self.line),
            "substep_ns": self.substep_ns,
        }
        if with_trials:
            offset = self.run_clock_offset_ns
            out["trials"] = [
                {
                    **t.to_json(),
                    "slip_events": [s.event_json(offset) for s in self.slips if s.trial_index == t.index],
                }
                for t in self.trials
            ]
            out["slips"] = [s.to_json() for s in self.slips]
        return out


def _slip_mix_json(mix: SlipKindMix) -> dict[str, Any]:
    return {
        "probabilities": {kind.value: p for kind, p in zip(SlipKind, mix.probabilities, strict=True)},
        **{k: list(v) for k, v in asdict(mix).items() if isinstance(v, tuple) and k != "probabilities"},
        "other_joint_report_probability": mix.other_joint_report_probability,
        "no_slip_capacity_factor": mix.no_slip_capacity_factor,
    }


@dataclass(frozen=True)
class RunTruth:
    """The truth of a simulated run at one moment: the world's, and the rig's state then."""

    final_tension_n: float  # the line's tension when the truth was taken
    torque_off: bool  # every servo's torque was off then
    world: WorldTruth

    @property
    def estimated_joint(self) -> int:
        """The joint a joint-estimation run estimates (1-based)."""
        return ESTIMATED_JOINT

    @property
    def estimated(self) -> CapacityTruth:
        """The estimated joint's true capacity, k and μs·δ0."""
        return self.world.joints[ESTIMATED_JOINT - 1]

    @property
    def k_kg_m(self) -> float:
        """The estimated joint's true k."""
        return self.estimated.k_kg_m

    @property
    def capacity_nm(self) -> float:
        """The estimated joint's true capacity."""
        return self.estimated.capacity_nm

    def to_json(self, *, with_trials: bool = True) -> dict[str, Any]:
        """The log's `sim_truth` (with every trial) or the `truth` of `rig run --json` (without)."""
        estimated = self.estimated
        return {
            "final_tension_n": self.final_tension_n,
            "torque_off": self.torque_off,
            "k": estimated.k_kg_m,
            "capacity_nm": estimated.capacity_nm,
            "mu_delta0_pa": estimated.mu_delta0_pa,
            "estimated_joint": ESTIMATED_JOINT,
            "joint_capacities_nm": [j.capacity_nm for j in self.world.joints],
            "world": self.world.to_json(with_trials=with_trials),
        }
