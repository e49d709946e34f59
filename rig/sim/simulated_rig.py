"""The built-in simulated rig: the real drivers on byte-level emulators, coupled to the simulated world.

Assembly, in the order time flows on every clock advance:

1. `SimWorld.advance_to` (a `VirtualClock` listener) integrates the physics in 1 ms substeps; each
   substep first lets the emulated servos move (`EmulatedBus.advance_to`), then computes the line
   tension from the winch angle, detects and applies slips, and writes the winch's load torque.
2. The emulated load cell (another listener, registered later) turns `SimWorld.tension_at` into
   `rig-lc1` lines at its sample rate, which the real `SerialLoadCell` driver parses.
3. The real `DynamixelServoBus` talks Protocol 2.0 to the emulated bus through `SimPortHandler`
   (dynamixel-sdk unchanged), so the winch's position, current and faults come back over the wire.

At the object level (`devices=DeviceLevel.OBJECT`) the same world, preset and seeds drive
`ObjectServoBus` and `ObjectLoadCell` (rig/sim/object_devices.py) instead of the real drivers on
emulators: no bytes, so timed faults and the cell's line-level options are refused there. The
listener order on the clock is the same.

The runner never tells the world that a trial begins. The simulated person (`SimulatedPerson`, the
session's `Operator`) does at once what the operator is asked: following a joint-estimation prompt
it hooks the line to the specimen at the trial's distance, asked to bend or straighten the link it
does so by hand (with its placement error). Forks bend the link through their bender servos and
the world's fork fixture (rig/sim/physics/forks.py). The world draws each loading's capacities
itself when the line becomes taut (rig/sim/physics/world.py). Its truth is returned beside the
session (`SimulatedRig.truth`), never through it.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol, assert_never

from rig.errors import ConfigError
from rig.hw.bending import BendStage, ForkBending, ManualBending, fork_components
from rig.hw.configuration.factory import hardware_configuration_source
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.seams import ConfigurationSource, LoadCell, ServoBus
from rig.hw.session import OperatorRequest, OperatorTask, RigSession
from rig.inputs.rig_config import RigConfig, configuration_source_kind
from rig.sim.dxl.emulated_bus import EmulatedBus
from rig.sim.dxl.inprocess_port import SimPortHandler
from rig.sim.fault_plan import FaultSchedule, apply_faults, loadcell_rate_faults, log_limit_bytes
from rig.sim.kinds import DeviceLevel
from rig.sim.loadcell.artefacts import ArtefactModel
from rig.sim.loadcell.emulator import LoadCellEmulator, SignalModel
from rig.sim.loadcell.inprocess_line import simulated_load_cell
from rig.sim.object_devices import ObjectLoadCell, ObjectServoBus
from rig.sim.physics.configuration_source import SimConfigurationSource
from rig.sim.physics.link_presets import STREAM_LOADCELL_ARTEFACTS, SimPreset, make_preset, stream_rng
from rig.sim.physics.world import ShaftLike, SimWorld
from rig.sim.settings import SimulationConfig, require_simulated, simulation_section, simulation_settings
from rig.sim.truth import RunTruth
from rig.sim.virtual_clock import DEFAULT_EPOCH_NS, VirtualClock
from rig.vocabulary import ConfigurationSourceKind, RigKind, TrialKind


class PacedVirtualClock(VirtualClock):
    """Virtual time that also waits in real time when it sleeps (`rig run --realtime`)."""

    def sleep(self, seconds: float) -> None:
        """Wait for real, then advance."""
        if seconds > 0:
            time.sleep(seconds)
        super().sleep(seconds)


class SimulatedPerson:
    """The operator of a simulated rig: does what it is asked at once, on the world, then confirms.

    Following a joint-estimation trial's prompt it hangs the hook at the trial's distance on the
    specimen (that trial's joint); following a link-validation trial's prompt it hooks the line to
    the link; asked to bend or straighten the link, it does so by hand.
    """

    def __init__(self, world: SimWorld) -> None:
        self.world = world
        self.requests: list[OperatorRequest] = []

    def confirm(self, request: OperatorRequest, keep_alive: Callable[[], None]) -> None:
        """Do the task on the world and return (the simulated person answers at once)."""
        self.requests.append(request)
        world, trial = self.world, request.trial
        match request.task:
            case OperatorTask.FOLLOW_PROMPT:
                if trial is not None and trial.kind is TrialKind.JOINT_ESTIMATION:
                    assert trial.distance_m is not None  # every joint-estimation trial has one
                    world.place_hook(trial.distance_m, trial.joint)
                elif trial is not None:
                    world.hook_link()
            case OperatorTask.BEND_LINK:
                world.bend_by_hand(request.joint_angles_rad or ())
            case OperatorTask.STRAIGHTEN_LINK:
                world.straighten()
            case task:
                assert_never(task)


class SimForkBending(ForkBending):
    """Forks on the simulated link: the world closes each fork as its stage begins (physics/forks.py)."""

    def __init__(self, world: SimWorld, config: RigConfig) -> None:
        article = config.article
        super().__init__(
            fork_components(config),
            article.segment_lengths_m,
            article.point_m,
            config.bending.pinion_radius_m,
        )
        self.world = world

    def begin_stage(self, stage: BendStage) -> None:
        """The fork closes on its component."""
        self.world.engage_fork(stage.component)

    def end_stage(self, stage: BendStage) -> None:
        """The fork has arrived: the link settles and the fork holds."""
        if self.world.forks is not None:
            self.world.forks.settle()

    def end_bend(self) -> None:
        """The forks open."""
        if self.world.forks is not None:
            self.world.forks.open()

    def home_goals(self) -> dict[int, float]:
        """The guide bar straightens the link; the forks go home."""
        self.world.straighten()
        return super().home_goals()


# Each invocation of a run (the first, then every --resume) starts its virtual clock a day after
# the previous one, so the parts of a resumed run never overlap in log time.
VIRTUAL_DAY_NS = 86_400 * 1_000_000_000


@dataclass(frozen=True)
class SimulatedDevices:
    """The simulation behind a session, for tests, fault injection and benchmarks (never the runner)."""

    bus: EmulatedBus | ObjectServoBus  # the servos behind the driver (byte level), or the session's own
    world: SimWorld
    loadcell_emulator: LoadCellEmulator | None  # behind the driver (byte level); None at object level
    faults: FaultSchedule  # the config's timed faults, and which of them fired (none at object level)


@dataclass(frozen=True)
class SimulatedRig:
    """A simulated rig: the session the runner drives, its truth beside it, the devices behind it.

    It is what `rig.runner.execute.execute_run` takes (`rig.runner.rig_to_run.RigToRun`).
    """

    session: RigSession
    devices: SimulatedDevices
    truth: SimGroundTruth
    person: SimulatedPerson
    log_limit_bytes: int | None = None  # a logger fault: the most the run's log file may hold

    @property
    def world(self) -> SimWorld:
        """The simulated world behind the devices."""
        return self.devices.world


class _TorqueServo(Protocol):
    @property
    def torque_enabled(self) -> bool: ...


class _ServoSet(Protocol):
    """A bus of emulated or object-level servos, for whether any still has torque on."""

    @property
    def servos(self) -> Sequence[_TorqueServo]: ...


class SimGroundTruth:
    """The world's hidden truth as the run reports it (`rig.hw.session.GroundTruth`)."""

    def __init__(self, world: SimWorld, bus: _ServoSet) -> None:
        self.world = world
        self.bus = bus

    def snapshot(self) -> RunTruth:
        """The world's truth with the rig's state now (the line's tension, whether torque is off)."""
        return RunTruth(
            final_tension_n=float(self.world.tension_n),
            torque_off=not any(servo.torque_enabled for servo in self.bus.servos),
            world=self.world.truth(),
        )


def simulated_rig(
    config: RigConfig,
    *,
    seed: int = 0,
    realtime: bool = False,
    invocation: int = 1,
    devices: DeviceLevel = DeviceLevel.BYTE,
) -> SimulatedRig:
    """The simulated rig of a `kind: simulated` config, seeded; nothing is connected yet.

    `invocation` (1 for a new run, 2 for its first resume, ...) sets the start of virtual time;
    `devices` chooses the real drivers on byte-level emulators or the object-level devices.
    """
    sim = require_simulated(config)
    preset = config_preset(config, seed)
    clock = run_clock(realtime, invocation)
    match DeviceLevel(devices):  # ValueError for a name that is no level
        case DeviceLevel.BYTE:
            behind, servos, load_cell = _byte_devices(config, sim, preset, clock, seed)
        case DeviceLevel.OBJECT:
            behind, servos, load_cell = _object_devices(config, sim, preset, clock, seed)
        case level:
            assert_never(level)
    world = behind.world
    person = SimulatedPerson(world)
    session = RigSession(
        kind=RigKind.SIMULATED,
        clock=clock,
        servos=servos,
        load_cell=load_cell,
        operator=person,
        fixture=bending_fixture(world, config),
        configuration=configuration_source(world, config, clock, seed),
        configuration_kind=configuration_source_kind(config),
        winch_id=config.servos.winch.servo_id,
        roles={s.servo_id: s.role for s in config.servos.servos},
        attachments=[("loadcell-calibration.json", "application/json", calibration_json(load_cell))],
    )
    truth = SimGroundTruth(world, behind.bus)
    return SimulatedRig(session, behind, truth, person, log_limit_bytes(sim.faults))


def _byte_devices(
    config: RigConfig, sim: SimulationConfig, preset: SimPreset, clock: VirtualClock, seed: int
) -> tuple[SimulatedDevices, ServoBus, LoadCell]:
    """The byte-level emulators in the world, and the real drivers on them."""
    ids = [s.servo_id for s in config.servos.servos]
    bus = EmulatedBus.with_servos(
        clock, ids=ids, model=emulated_models(config), baud=config.servos.baud, firmware=sim.servo_firmware
    )
    for servo in bus.servos:
        servo.supply_voltage_v = sim.servo_supply_v
        servo.set_temperature_c(sim.servo_temperature_c)
    world = new_world(preset, config, bus, clock, seed)
    load_cell, loadcell_emulator = simulated_load_cell(
        world.tension_at,
        clock,
        format_name=config.loadcell.format,
        rate_hz=sim.loadcell_rate_hz,
        signal=loadcell_signal(preset),
        faults=loadcell_rate_faults(sim.faults),
        seed=seed,
        stale_timeout_s=config.limits.stale_timeout_s,
        artefacts=loadcell_artefacts(preset, seed),
        baud=config.loadcell.baud,
        cell=sim.cell,
        clock_error_ppm=sim.loadcell_clock_error_ppm,
        dtr_reset_s=sim.loadcell_dtr_reset_s,
        boot_grace_s=config.loadcell.boot_grace_s,
    )
    schedule = apply_faults(config, sim.faults, bus=bus, loadcell=loadcell_emulator, clock=clock, seed=seed)
    servos = DynamixelServoBus(
        config.servos.port,
        config.servos.baud,
        config.servos.servos,
        clock,
        retries=config.servos.retries,
        bus_watchdog_ms=config.servos.watchdog_ms,
        port_factory=lambda name: SimPortHandler(bus, clock, name),
    )
    return SimulatedDevices(bus, world, loadcell_emulator, schedule), servos, load_cell


def _object_devices(
    config: RigConfig, sim: SimulationConfig, preset: SimPreset, clock: VirtualClock, seed: int
) -> tuple[SimulatedDevices, ServoBus, LoadCell]:
    """The object-level devices in the world (no bytes: timed faults and line-level options refused)."""
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
    return SimulatedDevices(bus, world, None, FaultSchedule()), bus, load_cell


def calibration_json(load_cell: Any) -> bytes:
    """The simulated cell's calibration as the JSON file a real rig would attach."""
    return (json.dumps(load_cell.calibration.to_dict(), indent=2, allow_nan=False) + "\n").encode()


class _ShaftBus(Protocol):
    """What the world needs of a servo bus (emulated or object-level): shafts by id and stepping."""

    def servo(self, servo_id: int) -> ShaftLike:
        """The servo's shaft."""
        ...

    def advance_to(self, t_ns: int) -> None:
        """Let the servos move up to `t_ns`."""
        ...


def config_preset(config: RigConfig, seed: int) -> SimPreset:
    """The seeded preset of a config's simulation (ConfigError naming the section if it is invalid)."""
    sim = simulation_section(config)
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
            slip_mix=sim.slips,
            scatter=sim.scatter,
            loadcell_artefacts=sim.loadcell,
        )
        if sim.spring_stiffness_n_per_m is not None:
            preset = replace(preset, spring_stiffness_n_per_m=sim.spring_stiffness_n_per_m)
        elif config.kind is RigKind.HARDWARE:
            # A lab's twin: its line is as stiff as the lab says its own is (`rig check --move`
            # measures it there, and `--write` must not put the preset's stiffness into the config).
            preset = replace(preset, line_stiffness_n_per_m=config.line_stiffness_n_per_m)
        if sim.initial_tension_n > 0:  # the line starts stretched by the drum travel that loads it so
            stretch_m = sim.initial_tension_n / preset.effective_line_stiffness_n_per_m
            preset = replace(preset, winch_slack_rad=-stretch_m / preset.drum_radius_m)
        return preset
    except ValueError as exc:
        raise ConfigError(f"{config.source}: simulation/article: {exc}") from None


class MirroredShaft:
    """The winch's shaft as a line wound onto the drum the other way sees it: angle and torque negated."""

    def __init__(self, shaft: ShaftLike) -> None:
        self._shaft = shaft

    @property
    def present_position_rad(self) -> float:
        """The shaft's angle, negated."""
        return -self._shaft.present_position_rad

    @property
    def external_torque_nm(self) -> float:
        """The line's torque on the shaft, in the mirrored direction."""
        return -self._shaft.external_torque_nm

    @external_torque_nm.setter
    def external_torque_nm(self, value: float) -> None:
        self._shaft.external_torque_nm = -value


def run_clock(realtime: bool, invocation: int) -> VirtualClock:
    """The virtual clock of a run; `invocation` (1: a new run, 2: its first resume, ...) sets its start."""
    epoch_ns = DEFAULT_EPOCH_NS + (invocation - 1) * VIRTUAL_DAY_NS
    return PacedVirtualClock(epoch_ns) if realtime else VirtualClock(epoch_ns)


def emulated_models(config: RigConfig) -> list[str]:
    """The model of each servo on the emulated bus, in `servos.ids` order.

    Each configured servo is its own model, unless `simulation.servo_models` puts others on the bus
    (a lab's mixed-up servo).
    """
    sim = simulation_settings(config)
    if sim is not None and sim.servo_models is not None:
        return [str(m) for m in sim.servo_models]
    return [s.model for s in config.servos.servos]


def new_world(
    preset: SimPreset, config: RigConfig, bus: _ShaftBus, clock: VirtualClock, seed: int
) -> SimWorld:
    """The world on the bus's winch and bender shafts, integrating on every advance of the clock."""
    benders = config.servos.benders
    winch: ShaftLike = bus.servo(config.servos.winch.servo_id)
    if simulation_section(config).winch_reversed:
        winch = MirroredShaft(winch)
    world = SimWorld(
        preset,
        winch,
        forks=[(s.component, bus.servo(s.servo_id)) for s in benders if s.component is not None],
        pinion_radius_m=config.bending.pinion_radius_m,
        step_devices=bus.advance_to,
        seed=seed,
        start_ns=clock.monotonic_ns(),
        run_clock_offset_ns=clock.time_ns() - clock.monotonic_ns(),
    )
    clock.on_advance(world.advance_to)
    return world


def loadcell_signal(preset: SimPreset) -> SignalModel:
    """The simulated cell's signal model at the preset's noise."""
    return SignalModel(noise_counts=preset.loadcell_noise_n * SignalModel().gain_counts_per_n)


def loadcell_artefacts(preset: SimPreset, seed: int) -> ArtefactModel | None:
    """The preset's load-cell artefacts on their own random stream, or None when there are none."""
    if not preset.loadcell_artefacts.active:
        return None
    return ArtefactModel(
        preset.loadcell_artefacts, int(stream_rng(seed, STREAM_LOADCELL_ARTEFACTS).integers(2**63))
    )


def bending_fixture(world: SimWorld, config: RigConfig) -> SimForkBending | ManualBending:
    """Forks where the config's benders name components; else the simulated person bends by hand."""
    return SimForkBending(world, config) if fork_components(config) else ManualBending()


def configuration_source(
    world: SimWorld, config: RigConfig, clock: VirtualClock, seed: int
) -> ConfigurationSource | None:
    """The source the config selects: the world's own for `simulator`, else the hardware factory's."""
    if configuration_source_kind(config) == ConfigurationSourceKind.SIMULATOR:
        return SimConfigurationSource(world, clock, seed=seed)
    return hardware_configuration_source(config, clock)
