"""The simulated rig on object-level devices: the same world, preset and seeds as `simulated_rig`, no bytes.

`object_simulated_rig` builds what `rig.sim.simulated_rig.simulated_rig` builds (the preset from
the config and seed, the virtual clock, `SimWorld` with the winch and bender shafts, the operator,
fixture, configuration source and truth) but puts `ObjectServoBus` and `ObjectLoadCell`
(`rig.sim.object_devices`) where the real drivers on emulators go. Listener order on the clock is
the same: the world integrates first (stepping the servos in its substeps), then the load cell
samples it. Timed faults (`simulation.faults`) act on the emulators' bytes and are refused here.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, cast

from rig.errors import ConfigError
from rig.hw.session import RigSession
from rig.protocol import TrialPlan
from rig.rig_config import RigConfig, require_simulated
from rig.sim.clock import DEFAULT_EPOCH_NS, VirtualClock
from rig.sim.loadcell.emulator import SignalModel
from rig.sim.object_devices import ObjectLoadCell, ObjectServoBus
from rig.sim.physics.article_presets import make_preset
from rig.sim.physics.configuration_source import SimConfigurationSource
from rig.sim.physics.world import SimWorld
from rig.sim.simulated_rig import (
    VIRTUAL_DAY_NS,
    PacedVirtualClock,
    SimBendingFixture,
    SimOperator,
    WorldTruth,
    _NoFixture,
)

DEVICE_LEVELS = ("byte", "object")


@dataclass(frozen=True)
class ObjectSimulatedRig:
    """A simulated rig on object-level devices: the session and what is behind it (tests, benchmarks)."""

    session: RigSession
    world: SimWorld
    bus: ObjectServoBus
    load_cell: ObjectLoadCell


def object_simulated_rig(
    config: RigConfig, *, seed: int = 0, realtime: bool = False, invocation: int = 1
) -> ObjectSimulatedRig:
    """The object-level simulated rig of a `kind: simulated` config, seeded; nothing connected yet."""
    sim = require_simulated(config)
    if sim.faults:
        raise ConfigError(
            f"{config.source}: simulation/faults: the object-level devices have no bytes to corrupt; "
            "allowed: no faults, or the byte-level devices (--devices byte)"
        )
    article = config.article
    try:
        preset = make_preset(
            sim.preset,
            seed,
            noise_scale=sim.noise_scale,
            torsion_weak_joint=sim.torsion_weak_joint,
            segment_lengths_m=article.segment_lengths_m,
            point_m=article.point_m,
            direction_w=article.direction,
            joint_radius_m=article.joint_radius_m,
            drum_radius_m=config.spool_radius_m,
            g=article.g,
        )
    except ValueError as exc:
        raise ConfigError(f"{config.source}: simulation/article: {exc}") from None
    epoch_ns = DEFAULT_EPOCH_NS + (invocation - 1) * VIRTUAL_DAY_NS
    clock: VirtualClock = PacedVirtualClock(epoch_ns) if realtime else VirtualClock(epoch_ns)
    winch_spec = config.servos.winch
    benders = config.servos.benders
    bus = ObjectServoBus(clock, [(s.servo_id, winch_spec.model) for s in config.servos.servos])
    world = SimWorld(
        preset,
        bus.servo(winch_spec.servo_id),
        bender=bus.servo(benders[0].servo_id) if benders else None,
        step_devices=bus.advance_to,
        seed=seed,
        start_ns=clock.monotonic_ns(),
    )
    clock.on_advance(world.advance_to)
    gain = SignalModel().gain_counts_per_n
    load_cell = ObjectLoadCell(
        world.tension_at,
        clock,
        rate_hz=sim.loadcell_rate_hz,
        signal=SignalModel(noise_counts=preset.loadcell_noise_n * gain),
        seed=seed,
    )

    def begin_trial(trial: TrialPlan) -> None:
        if trial.kind == "joint_estimation":
            world.begin_trial("joint_estimation", distance_m=trial.distance_m, joint=trial.joint)
        else:
            world.begin_trial("link_validation")

    calibration = json.dumps(load_cell.calibration.to_dict(), indent=2, allow_nan=False) + "\n"
    session = RigSession(
        kind="simulated",
        clock=clock,
        servos=bus,
        load_cell=load_cell,
        operator=SimOperator(),
        fixture=SimBendingFixture(world, benders[0].servo_id) if benders else _NoFixture(),
        configuration=SimConfigurationSource(world, clock, seed=seed),
        winch_id=winch_spec.servo_id,
        roles={s.servo_id: s.role for s in config.servos.servos},
        begin_trial=begin_trial,
        # WorldTruth reads only `bus.servos[*].torque_enabled`, which the object bus has too.
        truth=WorldTruth(world, cast(Any, bus)),
        attachments=[("loadcell-calibration.json", "application/json", calibration.encode())],
    )
    return ObjectSimulatedRig(session, world, bus, load_cell)
