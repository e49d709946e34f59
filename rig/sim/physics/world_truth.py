"""The simulated world's ground truth as a typed record: what it was made with, its trials and its slips."""

from __future__ import annotations

from typing import TYPE_CHECKING

from model.joint import mu_delta0_pa_from_capacity, resolve_constant
from rig.sim.truth import (
    CapacityTruth,
    GeometryTruth,
    LineTruth,
    NoiseTruth,
    ScatterTruth,
    WorldTruth,
)

if TYPE_CHECKING:
    from rig.sim.physics.world import SimWorld


def world_truth(world: SimWorld) -> WorldTruth:
    """The truth of `world` now: its preset, seed and line, every trial's draws and every slip so far."""
    p = world.preset
    constant = resolve_constant(p.constant)

    def capacity(capacity_nm: float) -> CapacityTruth:
        mu_delta0_pa = float(mu_delta0_pa_from_capacity(capacity_nm, p.joint_radius_m, constant))
        return CapacityTruth(capacity_nm, capacity_nm / p.g, mu_delta0_pa)

    return WorldTruth(
        preset=p.name,
        seed=world.seed,
        article_seed=p.seed,
        g=p.g,
        constant_name=constant.name,
        constant_c=constant.value,
        joint_radius_m=p.joint_radius_m,
        joints=tuple(capacity(c) for c in p.joint_capacities_nm),
        specimen=capacity(p.specimen_capacity_nm),
        noise=NoiseTruth(
            per_trial_capacity_sd=p.per_trial_capacity_sd,
            loadcell_noise_n=p.loadcell_noise_n,
            sigma_bend_rad=p.sigma_bend_rad,
            sigma_meas_rad=p.sigma_meas_rad,
            slipped_joint_report_probability=p.slipped_joint_report_probability,
        ),
        kinetic_ratio=p.kinetic_ratio,
        scatter=ScatterTruth(p.scatter_shape, p.scatter_a_kg, p.per_trial_capacity_sd),
        slip_mix=p.slip_mix,
        loadcell_artefacts=p.loadcell_artefacts,
        run_clock_offset_ns=world.run_clock_offset_ns,
        slip_rate_rad_s=p.slip_rate_rad_s,
        torsion_weak_joint=p.torsion_weak_joint,
        torsion_ratio=p.torsion_ratio,
        geometry=GeometryTruth(
            segment_lengths_m=tuple(p.segment_lengths_m),
            point_m=tuple(p.point_m),
            direction_w=tuple(p.unit_direction_w),
            joint_estimation_distances_m=tuple(p.joint_estimation_distances_m),
        ),
        line=LineTruth(
            drum_radius_m=p.drum_radius_m,
            line_stiffness_n_per_m=p.line_stiffness_n_per_m,
            spring_stiffness_n_per_m=p.spring_stiffness_n_per_m,
            effective_stiffness_n_per_m=world.line.stiffness_n_per_m,
            winch_slack_rad=p.winch_slack_rad,
        ),
        substep_ns=world.substep_ns,
        trials=tuple(world.trials),
        slips=tuple(s.truth() for s in world.slips),
    )
