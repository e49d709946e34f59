"""The simulated rig on object-level devices: the same world, preset and seeds as `simulated_rig`, no bytes.

`object_simulated_rig` builds what `rig.sim.simulated_rig.simulated_rig` builds (the preset from
the config and seed, the virtual clock, `SimWorld` with the winch and bender shafts, the operator,
fixture, configuration source and truth) but puts `ObjectServoBus` and `ObjectLoadCell`
(`rig.sim.object_devices`) where the real drivers on emulators go. Listener order on the clock is
the same: the world integrates first (stepping the servos in its substeps), then the load cell
samples it. Timed faults (`simulation.faults`) act on the emulators' bytes and are refused here.
"""

from __future__ import annotations

from dataclasses import dataclass

from rig.errors import ConfigError
from rig.hw.session import RigSession
from rig.rig_config import RigConfig
from rig.sim.object_devices import ObjectLoadCell, ObjectServoBus
from rig.sim.physics.world import SimWorld
from rig.sim.settings import require_simulated
from rig.sim.simulated_rig import (
    SimGroundTruth,
    SimOperator,
    bending_fixture,
    calibration_json,
    config_preset,
    configuration_source,
    emulated_models,
    loadcell_artefacts,
    loadcell_signal,
    new_world,
    run_clock,
    session_extras,
    trial_starter,
)
from rig.vocabulary import RigKind


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
    if sim.cell is not None or sim.loadcell_clock_error_ppm or sim.loadcell_dtr_reset_s:
        raise ConfigError(
            f"{config.source}: simulation.loadcell_cell: {sim.loadcell_cell} (clock error "
            f"{sim.loadcell_clock_error_ppm:g} ppm, DTR reset {sim.loadcell_dtr_reset_s:g} s): the "
            "object-level load cell has no lines, settling, polls or device clock; allowed: the default "
            "cell, or the byte-level devices (--devices byte)"
        )
    preset = config_preset(config, seed)
    clock = run_clock(realtime, invocation)
    models = emulated_models(config)  # as on the byte-level bus
    bus = ObjectServoBus(clock, [(s.servo_id, m) for s, m in zip(config.servos.servos, models, strict=True)])
    world = new_world(preset, config, bus, clock, seed)
    world.devices_at_rest = bus.at_rest
    load_cell = ObjectLoadCell(
        world.tension_at,
        clock,
        rate_hz=sim.loadcell_rate_hz,
        signal=loadcell_signal(preset),
        seed=seed,
        artefacts=loadcell_artefacts(preset, seed),
        tensions_n=world.tensions_at,
    )

    session = RigSession(
        kind=RigKind.SIMULATED,
        clock=clock,
        servos=bus,
        load_cell=load_cell,
        operator=SimOperator(),
        fixture=bending_fixture(world, config),
        configuration=configuration_source(world, config, clock, seed),
        winch_id=config.servos.winch.servo_id,
        roles={s.servo_id: s.role for s in config.servos.servos},
        begin_trial=trial_starter(world),
        truth=SimGroundTruth(world, bus),
        attachments=[("loadcell-calibration.json", "application/json", calibration_json(load_cell))],
        **session_extras(world, config),
    )
    return ObjectSimulatedRig(session, world, bus, load_cell)
