"""The rig's twin over the ports (`rig sim rig`): a config's simulated world behind its own serial ports.

The same world as the in-process simulated rig (rig/sim/simulated_rig.py: `SimWorld` on an
`EmulatedBus` with every configured servo as its own model, and a `LoadCellEmulator` of the line's
tension), but in real time and reached only through pseudo-terminals symlinked at the config's
`servos.port` and `loadcell.port`, so a hardware config's own commands drive it as they would the
rig. The existing pty servers do the serving, each in its own thread: `rig.sim.dxl.bus_pty_server.serve`
for the bus and `rig.sim.loadcell.line_pty_server.serve_loadcell` for the cell, or, with `firmware`,
the built firmware image under simavr fed the world's tension (rig/sim/twin_firmware.py).

Time: the world's `VirtualClock` reads the host's monotonic clock (its epoch makes `time_ns` the
wall clock), and is moved to the monotonic time now under one lock before every bus transaction,
before every load-cell sample, and every `TICK_S` in the main thread; the world integrates in its
1 ms substeps whatever the step. The lock keeps the world, the servos and the hand in one thread at a
time.

The person at the twin types `hang KG` / `unhang` on its console (rig/sim/twin_console.py) to
rehearse `rig calibrate`. Trials: the runner cannot tell the world that a trial begins over the
ports; the twin's hand (rig/sim/twin_hand.py) sets each up while the line is slack. The config's
`simulation.faults` on the servos and the load cell are applied as in-process, timed from the
twin's start; a load cell `disconnect` unplugs the cell's port for its window (rig/sim/twin_ports.py),
as the console's `unplug loadcell` does. A `host` or `logger` fault acts on the run, not on the
devices, and is refused; so is a load-cell fault with `--firmware` (the board under simavr is the
cell then, and the emulator the faults act on is not served).

The ports: each device is served by its own thread on a `ServedPort`, which the main thread brings
every `TICK_S` to the condition the person asked at the console (`unplug`, `replug`, `freeze`,
`thaw`; rig/sim/twin_console.py) or a configured disconnect holds.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from rig.errors import ConfigError
from rig.hw.loadcell.calibration import Calibration
from rig.inputs.protocol import Protocol
from rig.inputs.rig_config import RigConfig
from rig.sim.dxl.bus_pty_server import serve
from rig.sim.dxl.emulated_bus import EmulatedBus, Reply
from rig.sim.fault_plan import FaultSchedule, apply_faults, loadcell_rate_faults
from rig.sim.kinds import FaultDevice
from rig.sim.loadcell.emulator import LoadCellEmulator
from rig.sim.loadcell.inprocess_line import ideal_calibration, simulated_load_cell
from rig.sim.loadcell.line_pty_server import serve_loadcell
from rig.sim.physics.world import SimWorld
from rig.sim.pty_port import PtyPort, Stop
from rig.sim.settings import simulation_section
from rig.sim.simulated_rig import (
    config_preset,
    emulated_models,
    loadcell_artefacts,
    loadcell_signal,
    new_world,
)
from rig.sim.truth import RunTruth
from rig.sim.twin_console import ReferenceLoad
from rig.sim.twin_firmware import feed_firmware, harness_command, start_firmware_cell, stop_firmware_cell
from rig.sim.twin_hand import HandTrial, TwinHand, hand_trials
from rig.sim.twin_ports import PortAction, PortCondition, PortRequests, ServedPort, TwinDevice
from rig.sim.virtual_clock import VirtualClock
from rig.vocabulary import LOADCELL_FORMAT_TRAITS

TICK_S = 0.01  # how often the main thread brings the world up to the wall clock when nothing else does
DONE_FORCE_FRACTION = 0.95  # a trial that reaches this share of the ramp's max_force_n is over


class _LockedBus:
    """The emulated bus as the pty server feeds it: the world brought up to the time first, under the lock."""

    def __init__(self, twin: Twin) -> None:
        self._twin = twin

    @property
    def baud(self) -> int:
        """The host's line rate."""
        return self._twin.bus.baud

    @baud.setter
    def baud(self, value: int) -> None:
        self._twin.bus.baud = value

    def feed(self, data: bytes, now_ns: int) -> list[Reply]:
        """The replies to the host's bytes, after the world has moved to `now_ns`."""
        with self._twin.lock:
            self._twin.clock.advance_to_ns(now_ns)
            return self._twin.bus.feed(data, now_ns)


@dataclass
class Twin:
    """A config's world, its emulated devices and the simulated hand, on a clock that follows the wall."""

    config: RigConfig
    clock: VirtualClock
    bus: EmulatedBus
    world: SimWorld
    loadcell: LoadCellEmulator
    faults: FaultSchedule
    hand: TwinHand
    lock: threading.Lock
    reference: ReferenceLoad  # a mass hung in the line by hand (the console's `hang`)
    seed: int
    ports: PortRequests = field(default_factory=PortRequests)  # unplugged or frozen by the person

    def act(self, action: PortAction, device: TwinDevice, seconds: float | None = None) -> str:
        """The person does `action` to `device`'s port (for `seconds`); what was done, one line."""
        return self.ports.ask(action, device, time.monotonic_ns(), seconds)

    def port_wanted(self, device: TwinDevice, now_ns: int) -> PortCondition:
        """The condition `device`'s port is to be in: the person's, or the cell's configured disconnect."""
        if device is TwinDevice.LOADCELL and self.loadcell.unplugged:  # simulation.faults: disconnect
            return PortCondition.UNPLUGGED
        return self.ports.wanted(device, now_ns)

    def status(self) -> str:
        """One line: the line's tension, the servos whose torque is on, and each port's condition."""
        now_ns = time.monotonic_ns()
        with self.lock:
            self.clock.advance_to_ns(now_ns)
            tension_n = float(self.world.tension_n)
            torque_on = [servo.servo_id for servo in self.bus.servos if servo.torque_enabled]
        servos = ", ".join(str(i) for i in torque_on) or "none"
        ports = "; ".join(f"{device}: {self.port_wanted(device, now_ns)}" for device in TwinDevice)
        return f"line {tension_n:.3f} N; torque on: {servos}; {ports}"

    def catch_up(self) -> None:
        """Integrate the world up to the monotonic time now."""
        with self.lock:
            self.clock.advance_to_ns(time.monotonic_ns())

    def tension_now_n(self) -> float:
        """What the load cell's input is now: the line's tension, and any mass hung by hand [N]."""
        with self.lock:
            self.clock.advance_to_ns(time.monotonic_ns())
            line_n = self.world.tension_n
        return line_n + self.reference.read_n()

    def set_up_trial(self, number: int) -> str:
        """The hand sets up the protocol's trial `number` (1-based) and goes on from it; what it did."""
        with self.lock:
            trial = self.hand.set_up(number - 1)
        where = "" if trial.distance_m is None else f", the hook at {trial.distance_m:g} m"
        return f"trial {number} set up ({trial.kind}{where})"

    def truth(self) -> RunTruth:
        """The world's truth now, with the line's tension and whether every servo's torque is off."""
        with self.lock:
            return RunTruth(
                final_tension_n=float(self.world.tension_n),
                torque_off=not any(servo.torque_enabled for servo in self.bus.servos),
                world=self.world.truth(),
            )

    def calibration(self) -> Calibration:
        """The calibration a perfect `rig calibrate` would find for the twin's cell at power-on."""
        return ideal_calibration(self.loadcell)


def wall_clock() -> VirtualClock:
    """A virtual clock at the host's monotonic time now, whose `time_ns` is the wall clock."""
    clock = VirtualClock(epoch_ns=time.time_ns() - time.monotonic_ns())
    clock.advance_to_ns(time.monotonic_ns())
    return clock


def twin_loadcell_rate_hz(config: RigConfig) -> float:
    """The twin cell's rate: the config's `loadcell.rate_hz`, else the simulation's."""
    sim = simulation_section(config)
    rate_hz = config.loadcell.rate_hz if config.loadcell.rate_hz is not None else sim.loadcell_rate_hz
    traits = LOADCELL_FORMAT_TRAITS[config.loadcell.format]
    if rate_hz > traits.max_rate_hz(config.loadcell.baud):
        raise ConfigError(
            f"{config.source}: simulation.loadcell_rate_hz: {rate_hz:g} lines/s do not fit loadcell.baud "
            f"{config.loadcell.baud}; allowed: at most {traits.max_rate_hz(config.loadcell.baud):.1f}, "
            "or set loadcell.rate_hz"
        )
    return rate_hz


def _check_twin_ports(config: RigConfig) -> None:
    """Both ports must be paths where a link can go (not `sim://...`), and not the same one."""
    for field_name, port in (("servos.port", config.servos.port), ("loadcell.port", config.loadcell.port)):
        if "://" in str(port):
            raise ConfigError(
                f"{config.source}: {field_name}: {port}; allowed in `rig sim rig`: a file-system path where "
                "the twin makes a symlink to its pty (an in-process or URL port has no path)"
            )
    if Path(config.servos.port) == Path(config.loadcell.port):
        raise ConfigError(
            f"{config.source}: loadcell.port: {config.loadcell.port}; allowed: another path than servos.port"
        )


def _check_twin_faults(config: RigConfig) -> None:
    for index, fault in enumerate(simulation_section(config).faults):
        if fault.device in (FaultDevice.HOST, FaultDevice.LOGGER):
            raise ConfigError(
                f"{config.source}: simulation.faults[{index}].device: {fault.device}; allowed in "
                "`rig sim rig`: servos, winch, bender, loadcell (a host or logger fault acts on the run)"
            )


def build_twin(config: RigConfig, *, seed: int = 0, protocol: Protocol | None = None) -> Twin:
    """The twin of `config` (its `simulation:` section), its hand following `protocol`; nothing served yet."""
    sim = simulation_section(config)
    cell = sim.cell
    if cell is not None and cell.format != config.loadcell.format:
        raise ConfigError(
            f"{config.source}: loadcell.format: {config.loadcell.format}; allowed: {cell.format}, the format "
            f"of simulation.loadcell_cell {sim.loadcell_cell}"
        )
    _check_twin_ports(config)
    _check_twin_faults(config)
    rate_hz = twin_loadcell_rate_hz(config)
    preset = config_preset(config, seed)
    clock = wall_clock()
    bus = EmulatedBus.with_servos(
        clock,
        ids=[s.servo_id for s in config.servos.servos],
        model=emulated_models(config),
        baud=config.servos.baud,
        firmware=sim.servo_firmware,
    )
    for servo in bus.servos:
        servo.supply_voltage_v = sim.servo_supply_v
        servo.set_temperature_c(sim.servo_temperature_c)
    world = new_world(preset, config, bus, clock, seed)
    lock = threading.Lock()
    reference = ReferenceLoad()

    def tension_n(t_ns: int) -> float:  # the cell's thread samples the world, and any mass hung by hand
        with lock:
            clock.advance_to_ns(time.monotonic_ns())
            try:
                line_n = world.tension_at(t_ns)
            except ValueError:  # older than the world's history: the twin was stopped (SIGSTOP) a while
                line_n = world.tension_n
        return line_n + reference.read_n()

    _, emulator = simulated_load_cell(
        tension_n,
        clock,
        format_name=config.loadcell.format,
        rate_hz=rate_hz,
        signal=loadcell_signal(preset),
        faults=loadcell_rate_faults(sim.faults),
        seed=seed,
        artefacts=loadcell_artefacts(preset, seed),
        baud=config.loadcell.baud,
        cell=cell,
        clock_error_ppm=sim.loadcell_clock_error_ppm,
        dtr_reset_s=sim.loadcell_dtr_reset_s,
    )
    schedule = apply_faults(config, sim.faults, bus=bus, loadcell=emulator, clock=clock, seed=seed)
    trials: list[HandTrial] = [] if protocol is None else hand_trials(protocol)
    done_force_n = float("inf") if protocol is None else DONE_FORCE_FRACTION * protocol.ramp.max_force_n
    hand = TwinHand(world, trials, done_force_n=done_force_n)
    clock.on_advance(hand.advance_to)
    return Twin(config, clock, bus, world, emulator, schedule, hand, lock, reference, seed)


def serve_pty(path: Path, field_name: str, config: RigConfig) -> PtyPort:
    """A pty symlinked at a port the config names (a ConfigError naming the field if it cannot be made)."""
    try:
        return PtyPort(path)
    except (OSError, ValueError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ConfigError(
            f"{config.source}: {field_name}: {path}: cannot serve there ({reason}); allowed: a new path or "
            "an old symlink in a writable directory"
        ) from None


@dataclass(frozen=True)
class Served:
    """Where one of the twin's devices is served: the config's port (a symlink) and the pty behind it."""

    link: Path
    device: str


PortChanged = Callable[[TwinDevice, PortCondition, Served | None], None]


def serve_twin(
    twin: Twin,
    stop: Stop,
    *,
    ready: Callable[[Served, Served], None],
    firmware: Path | None = None,
    changed: PortChanged | None = None,
) -> None:
    """Serve the twin on the config's ports until `stop`; `ready(servos, loadcell)` once they exist.

    `firmware`: the harness that runs the built image as the load cell (rig/sim/twin_firmware.py)
    instead of the Python emulator; the cell's port is then the harness's, not unplugged or frozen
    by the twin. Each device's server runs in its own thread; an error in one stops them all and is
    raised here. Every `TICK_S` the ports are brought to the condition the person asked
    (rig/sim/twin_ports.py); `changed(device, condition, served)` hears of each change after `ready`
    (`served`: where the port is now, None while unplugged).
    """
    config = twin.config
    command = None
    if firmware is not None:
        _check_firmware_faults(config)
        reset_s = simulation_section(config).loadcell_dtr_reset_s
        command = harness_command(firmware, config, twin_loadcell_rate_hz(config), reset_s)
    errors: list[BaseException] = []

    def start_guarded(target: Callable[[], object]) -> threading.Thread:
        def body() -> None:
            try:
                target()
            except BaseException as exc:  # handed to the main thread, which raises it
                errors.append(exc)
                stop.stopped = True

        thread = threading.Thread(target=body, daemon=True)
        thread.start()
        return thread

    def serve_bus(pty: PtyPort, device_stop: Stop) -> object:
        return serve(_LockedBus(twin), pty, device_stop)

    def serve_cell(pty: PtyPort, device_stop: Stop) -> object:
        return serve_loadcell(twin.loadcell, pty, device_stop)

    def drop_owed_lines(_: PtyPort) -> None:  # the cell's lines of the time it was not served are lost
        twin.loadcell.lines_until(time.monotonic_ns())

    ports: dict[TwinDevice, ServedPort] = {}
    feeder: threading.Thread | None = None
    with contextlib.ExitStack() as stack:

        def open_port(field_name: str, path: str) -> Callable[[], PtyPort]:
            return lambda: serve_pty(Path(path), field_name, config)

        ports[TwinDevice.SERVOS] = ServedPort(
            open_port("servos.port", config.servos.port),
            serve_bus,
            _drop_host_bytes,
            start_guarded,
        )
        stack.callback(ports[TwinDevice.SERVOS].close)
        if command is None:
            ports[TwinDevice.LOADCELL] = ServedPort(
                open_port("loadcell.port", config.loadcell.port),
                serve_cell,
                drop_owed_lines,
                start_guarded,
            )
            stack.callback(ports[TwinDevice.LOADCELL].close)
        else:
            twin.ports.refuse(TwinDevice.LOADCELL, "the firmware's harness serves this port (--firmware)")
            board = start_firmware_cell(command, Path(config.loadcell.port))
            stack.callback(stop_firmware_cell, board)
            signal = twin.loadcell.signal
            feeder = start_guarded(
                lambda: feed_firmware(board, twin.tension_now_n, signal, twin.seed, lambda: stop.stopped)
            )
        for device, port in ports.items():
            port.settle(twin.port_wanted(device, time.monotonic_ns()))
        served_cell = ports.get(TwinDevice.LOADCELL)
        cell = Served(board.link, board.device) if served_cell is None else _served(served_cell)
        ready(_served(ports[TwinDevice.SERVOS]), cell)
        try:
            while not stop.stopped:
                twin.catch_up()
                now_ns = time.monotonic_ns()
                for device, port in ports.items():
                    if port.settle(twin.port_wanted(device, now_ns)) and changed is not None:
                        changed(device, port.condition, None if port.pty is None else _served(port))
                time.sleep(TICK_S)
        finally:
            stop.stopped = True
            for port in ports.values():
                port.close()
            if feeder is not None:
                feeder.join()
    if errors:
        raise errors[0]


def _check_firmware_faults(config: RigConfig) -> None:
    for index, fault in enumerate(simulation_section(config).faults):
        if fault.device is FaultDevice.LOADCELL:
            raise ConfigError(
                f"{config.source}: simulation.faults[{index}].device: {fault.device}; allowed with "
                "--firmware: servos, winch, bender (the board under simavr is the cell, not the emulator "
                "the faults act on)"
            )


def _served(port: ServedPort) -> Served:
    assert port.pty is not None
    return Served(port.pty.link_path, port.pty.slave_name)


def _drop_host_bytes(pty: PtyPort) -> None:
    """What the host wrote to a port that did not pass it on (frozen) never reaches the servos."""
    while pty.read():
        pass
