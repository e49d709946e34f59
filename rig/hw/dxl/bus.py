"""The real Dynamixel bus driver: `DynamixelServoBus` implements `seams.ServoBus` on dynamixel-sdk.

What this module owns: the servos' meaning. The handshake, SI units at its boundary, limits
checked before anything is sent, hardware-fault detection and reboot recovery, and a shutdown that
cannot be skipped. Every exchange goes through `rig.hw.dxl.transport.Transport` (retries, reply
checks, counters, one owner); discovery without a config is `rig.hw.dxl.discovery`.

Design decisions (see docs/design.md §7 for the facts behind them):

* **State in one transaction.** `read_states` reads the contiguous block Moving(122) ..
  Present Position(132..135) of every servo with one Fast Sync Read when every servo's firmware
  is >= 45, else one Sync Read. Hardware Error Status(70) is *not* read every cycle: the Alert bit
  (0x80) of the ERR byte is set in every status packet while that register is non-zero, so the
  driver reads register 70 of a servo only when its status packet carries the Alert bit. The
  healthy cycle thus costs one transaction, with no indirect-address setup to restore after a
  reboot, and a fault is still seen within the same read.
* **Alert policy.** A state read *records* a fault in `ServoState.hardware_error` (the runner
  needs the positions and currents of that very cycle to log and act; its interlock checks the
  field, or calls `raise_for_hardware_errors`). A command or unicast read that gets the Alert bit
  *raises* `ServoHardwareFault` (a `HardwareFault` naming servo, role and decoded words), since a
  faulted servo has dropped torque and cannot carry the command out. Torque-off and reboot ignore
  the Alert bit: they are the remedy. Sync writes are broadcast and get no reply; their effect is
  seen by the next read.
* **Safety.** `shutdown(release)` runs the caller's release action, then torques every servo off
  (a broadcast sync write, then a confirmed write per servo), then closes the port; it keeps going
  through failures, defers Ctrl-C while torquing off, and re-raises the first error. The bus
  watchdog (address 98) is set when `bus_watchdog_ms` > 0: if the host crashes or stops talking
  for that long, the servos stop by themselves (they hold position with torque on, and refuse
  goals, until a host clears the watchdog). This driver clears it on connect, after a reboot, and
  mid-run: a state read that follows a quiet bus (no answer for 80 % of the window: a host pause,
  a bus that went silent) reads register 98 of every servo, clears a trip (writes 0, re-arms) and
  counts it (`BusStats.watchdog_trips`); `take_watchdog_trips` hands the trips to the runner to log.
"""

from __future__ import annotations

import contextlib
import math
import signal
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import TracebackType
from typing import Protocol

from dynamixel_sdk import COMM_SUCCESS, PortHandler

from rig.errors import (
    CommunicationError,
    HandshakeError,
    InputError,
    LimitError,
    NotConnectedError,
    RigTimeoutError,
)
from rig.hw.dxl import control_table as ct
from rig.hw.dxl import units as units
from rig.hw.dxl.error_codes import (
    ALERT_BIT,
    ERROR_NUMBER_MASK,
    InstructionRejected,
    ServoHardwareFault,
    error_number_name,
    hardware_fault,
    servo_label,
)
from rig.hw.dxl.transport import BusStats, Transport
from rig.hw.seams import Clock, OperatingMode, ServoState
from rig.hw.usb_latency import DEFAULT_SYSFS_ROOT, is_slow, latency_timer_cause, read_latency_timer_ms
from rig.safety.interrupts import signals_deferred

STATUS_RETURN_ALL = 2
# The handshake pings each servo up to this many rounds (each with the transport's retries), pausing
# between rounds: transient reply loss must not fail a connect.
HANDSHAKE_ROUNDS = 3
HANDSHAKE_PAUSE_S = 0.05
POSITION_MODES = (
    OperatingMode.POSITION,
    OperatingMode.EXTENDED_POSITION,
    OperatingMode.CURRENT_BASED_POSITION,
)

# Fields that bound the per-cycle state block (122..135); every X430 model has them.
STATE_FIELDS = ("Moving", "Present Velocity", "Present Position")
# Inside the block where the model has it; XL430 reports Present Load (0.1 %) there instead.
CURRENT_FIELD = "Present Current"


class ServoSpecLike(Protocol):
    """What the driver needs to know about one configured servo (`rig_config.ServoSpec` fits)."""

    @property
    def servo_id(self) -> int: ...

    @property
    def role(self) -> str: ...

    @property
    def model(self) -> str: ...


@dataclass(frozen=True, slots=True)
class ServoInfo:
    """What the handshake found for one servo."""

    servo_id: int
    role: str
    model: str
    model_number: int
    firmware: int


@dataclass(frozen=True, slots=True)
class ServoHealthReport:
    """One reading of a servo's slow-changing health values (`read_health`), in SI units.

    Not to be confused with the runner's `interlocks.ServoHealth`, the check that trips on a fault.
    """

    servo_id: int
    input_voltage_v: float
    temperature_c: float
    hardware_error: int
    time_ns: int


@dataclass(frozen=True, slots=True)
class WatchdogTrip:
    """A servo's Bus Watchdog found tripped (register 98 read -1) and cleared by the driver.

    `quiet_s` is how long the host had heard nothing from the bus before the read that found it.
    While tripped the servo held where it was and refused every goal write (Data Range error).
    """

    servo_id: int
    role: str
    quiet_s: float

    def describe(self) -> str:
        """One line for the log."""
        return (
            f"{servo_label(self.servo_id, self.role)}: Bus Watchdog tripped (the bus was quiet for "
            f"{self.quiet_s:.2f} s); it held its position and refused goals until cleared; cleared and "
            "re-armed"
        )


@dataclass(slots=True)
class _Servo:
    """Everything the driver tracks per servo: identity, table, and the RAM settings to restore."""

    spec: ServoSpecLike
    table: ct.ControlTable
    model_number: int = 0
    firmware: int = 0
    mode: int = int(OperatingMode.POSITION)
    torque_enabled: bool = False  # what the driver believes the servo is doing
    torque_wanted: bool = False  # what the host last asked for (restored after a reboot)
    goal_current_raw: int | None = None
    current_limit_raw: int | None = None
    profile_velocity_raw: int = 0
    profile_acceleration_raw: int = 0
    min_position_raw: int = 0
    max_position_raw: int = 4095
    hardware_error: int = 0
    current_offset: int | None = None  # of Present Current in the state block; None: not reported

    @property
    def label(self) -> str:
        return servo_label(self.spec.servo_id, self.spec.role)


def _field(table: ct.ControlTable, name: str) -> ct.Field | None:
    """The named field of a model's table, or None when the model does not have it."""
    return table.get(name)


def _require(table: ct.ControlTable, name: str) -> ct.Field:
    field = _field(table, name)
    if field is None:
        raise NotConnectedError(f"model {table.model_name} has no control-table field {name!r}")
    return field


class DynamixelServoBus:
    """A Dynamixel Protocol 2.0 bus on one serial port, owned by one thread.

    Args:
        port_name: serial device, e.g. "/dev/ttyUSB0" (or a pty link in simulation).
        baud: bus baud rate; must be one dynamixel-sdk can set.
        servos: the configured servos (id, role, expected model name).
        clock: the run's clock; used for time stamps, reboot polling and retry settling.
        retries: extra tries after a failed exchange (0 = try once).
        port_factory: builds the SDK port handler from the port name (inject the emulator here).
        fast_sync_read: force (True) or forbid (False) Fast Sync Read; None = when every servo's
            firmware allows it (>= 45).
        bus_watchdog_ms: bus watchdog window set on connect (multiples of 20 ms, <= 2540); 0 = off.
        max_reboots: reboots allowed per run (per driver instance), over all servos.
        reboot_timeout_s: how long to poll a rebooting servo with pings.
        retry_settle_s: quiet time before a retry, so a late reply is discarded rather than
            taken for the answer to the retry.
        sysfs_root: where the port's USB latency timer is read at connect (`rig.hw.usb_latency`).

    Use as a context manager (`with DynamixelServoBus(...) as bus:`): enter connects, exit calls
    `shutdown(release)` with the `release` given here.
    """

    def __init__(
        self,
        port_name: str,
        baud: int,
        servos: Sequence[ServoSpecLike],
        clock: Clock,
        *,
        retries: int = 2,
        port_factory: Callable[[str], PortHandler] = PortHandler,
        fast_sync_read: bool | None = None,
        bus_watchdog_ms: int = 0,
        max_reboots: int = 3,
        reboot_timeout_s: float = 3.0,
        retry_settle_s: float = 0.002,
        release: Callable[[], None] | None = None,
        sysfs_root: Path = DEFAULT_SYSFS_ROOT,
    ) -> None:
        if baud not in ct.SDK_BAUDS:
            raise InputError(f"servo bus baud {baud} cannot be set by dynamixel-sdk; allowed: {ct.SDK_BAUDS}")
        if not servos:
            raise InputError("servo bus: no servos configured; allowed: one or more IDs 0-252")
        ids = [s.servo_id for s in servos]
        for servo_id in ids:
            if not 0 <= servo_id <= 252:
                raise InputError(f"servo id {servo_id} is out of range; allowed: 0-252")
        duplicates = sorted({i for i in ids if ids.count(i) > 1})
        if duplicates:
            raise InputError(f"servo ids {duplicates} appear more than once; each id must be unique")
        if not 0 <= retries <= 10:
            raise InputError(f"servo bus retries {retries} is out of range; allowed: 0-10")
        if not 0 <= bus_watchdog_ms <= 127 * ct.BUS_WATCHDOG_UNIT_MS:
            raise InputError(f"bus watchdog {bus_watchdog_ms} ms is out of range; allowed: 0-2540 ms")
        if max_reboots < 0:
            raise InputError(f"max_reboots {max_reboots} is out of range; allowed: >= 0")
        self._servos: dict[int, _Servo] = {}
        for spec in servos:
            number = ct.model_number_for(spec.model)
            self._servos[spec.servo_id] = _Servo(spec=spec, table=ct.MODELS_BY_NUMBER[number])
        self._expected_numbers = {s.servo_id: ct.model_number_for(s.model) for s in servos}
        self.port_name = port_name
        self.baud = baud
        self._clock = clock
        self._link = Transport(
            port_name,
            clock,
            {s.servo_id: s.role for s in servos},
            retries=retries,
            retry_settle_s=retry_settle_s,
            port_factory=port_factory,
        )
        self._fast_sync_read_option = fast_sync_read
        self._bus_watchdog_ms = bus_watchdog_ms
        self._max_reboots = max_reboots
        self._reboot_timeout_s = reboot_timeout_s
        self._release = release
        self._sysfs_root = sysfs_root
        self._latency_timer_ms: int | None = None
        self._connected = False
        self._shut_down = False
        self._use_fast_read = False
        self._reboots_done = 0
        # The state block: same addresses for every model on one bus (checked on connect).
        self._block_start = 0
        self._block_length = 0
        self._offsets: dict[str, int] = {}
        self._state_ids: list[int] = list(self._servos)
        # Bus Watchdog trips: when the host heard nothing for most of the window (a host pause, a
        # bus that went quiet), the next state read checks register 98 of every servo.
        self._last_answer_ns: int | None = None
        self._watchdog_trips: list[WatchdogTrip] = []

    # ------------------------------------------------------------------ properties

    @property
    def servo_ids(self) -> list[int]:
        """Configured servo IDs, in configuration order."""
        return list(self._servos)

    @property
    def roles(self) -> dict[int, str]:
        """Role of each configured servo."""
        return {i: s.spec.role for i, s in self._servos.items()}

    @property
    def connected(self) -> bool:
        """True between a successful `connect` and `shutdown`."""
        return self._connected

    @property
    def uses_fast_sync_read(self) -> bool:
        """Whether `read_states` uses Fast Sync Read (decided on connect)."""
        return self._use_fast_read

    @property
    def latency_timer_ms(self) -> int | None:
        """The port's USB latency timer, read at connect (`PortLatencySource`); None if it has none."""
        return self._latency_timer_ms

    @property
    def stats(self) -> BusStats:
        """A copy of the bus counters."""
        return replace(self._link.stats)

    @property
    def reboots_left(self) -> int:
        """How many more reboots this run allows."""
        return self._max_reboots - self._reboots_done

    def info(self) -> dict[int, ServoInfo]:
        """What the handshake found: model and firmware of every servo."""
        self._require_connected()
        return {
            i: ServoInfo(i, s.spec.role, s.table.model_name, s.model_number, s.firmware)
            for i, s in self._servos.items()
        }

    def operating_mode(self, servo_id: int) -> OperatingMode:
        """The operating mode the driver last set or read for a servo."""
        return OperatingMode(self._servo(servo_id).mode)

    def hardware_errors(self) -> dict[int, int]:
        """The last Hardware Error Status seen per servo (0 = healthy)."""
        return {i: s.hardware_error for i, s in self._servos.items()}

    # ------------------------------------------------------------------ context manager

    def __enter__(self) -> DynamixelServoBus:
        self.connect()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.shutdown(self._release)

    # ------------------------------------------------------------------ connect

    def connect(self) -> None:
        """Open the port, set the baud rate, handshake and configure every servo.

        Raises:
            NotConnectedError: the port cannot be opened.
            HandshakeError: IDs missing or models not as configured (one message lists them all).
            RigTimeoutError, CommunicationError: a configuration exchange failed after the retries.
        """
        if self._connected:
            return
        if self._shut_down:
            raise NotConnectedError(f"servo bus on {self.port_name} was shut down; make a new one")
        self._link.open(self.baud)
        latency_ms = read_latency_timer_ms(self.port_name, self._sysfs_root)
        self._latency_timer_ms = latency_ms
        self._link.timeout_cause = (
            latency_timer_cause(latency_ms) if latency_ms and is_slow(latency_ms) else ""
        )
        try:
            self._handshake()
            self._decide_state_block()
            for servo in self._servos.values():
                self._configure(servo)
        except BaseException:
            self._link.close_quietly()
            raise
        self._connected = True

    def _ping_patiently(self, servo_id: int) -> int:
        """A handshake ping: `HANDSHAKE_ROUNDS` rounds of the transport's retries, paused between."""
        for round_left in reversed(range(HANDSHAKE_ROUNDS)):
            try:
                return self._link.ping(servo_id)
            except (RigTimeoutError, CommunicationError):
                if not round_left:
                    raise
                self._clock.sleep(HANDSHAKE_PAUSE_S)
        raise AssertionError("unreachable")

    def _handshake(self) -> None:
        missing: list[str] = []
        mismatched: list[str] = []
        unreadable: list[str] = []
        missing_ids: list[int] = []
        wrong_models: list[tuple[int, str]] = []
        for servo_id, servo in self._servos.items():
            try:
                found = self._ping_patiently(servo_id)
            except RigTimeoutError:
                missing.append(servo.label)
                missing_ids.append(servo_id)
                continue
            except CommunicationError as exc:
                unreadable.append(f"{servo.label}: {exc}")
                continue
            expected = self._expected_numbers[servo_id]
            if found != expected:
                mismatched.append(
                    f"{servo.label} expected {servo.table.model_name} ({expected}), "
                    f"found {ct.model_name_for(found)} ({found})"
                )
                wrong_models.append((servo_id, ct.model_name_for(found)))
                continue
            servo.model_number = found
            servo.firmware = self._read(servo, "Firmware Version", alerts="record")
        problems = []
        if missing:
            problems.append(f"missing: {'; '.join(missing)}")
        if mismatched:
            problems.append(f"wrong model: {'; '.join(mismatched)}")
        if unreadable:
            problems.append(f"unreadable: {'; '.join(unreadable)}")
        if problems:
            raise HandshakeError(
                f"servo handshake on {self.port_name} at {self.baud} baud failed "
                f"(after {1 + self._link.retries} tries per servo): " + " | ".join(problems),
                missing_ids=tuple(missing_ids),
                wrong_models=tuple(wrong_models),
            )
        if self._fast_sync_read_option is None:
            self._use_fast_read = all(s.firmware >= ct.FAST_READ_MIN_FIRMWARE for s in self._servos.values())
        else:
            self._use_fast_read = self._fast_sync_read_option

    def _decide_state_block(self) -> None:
        """One block, Moving(122) .. Present Position(132..135), with the same layout on every servo."""
        layouts = set()
        for servo in self._servos.values():
            fields = [_require(servo.table, n) for n in STATE_FIELDS]
            start = min(f.address for f in fields)
            end = max(f.end for f in fields)
            layouts.add((start, end, tuple((f.name, f.address - start) for f in fields)))
            current = _field(servo.table, CURRENT_FIELD)
            servo.current_offset = current.address - start if current is not None else None
        if len(layouts) != 1:
            raise HandshakeError(
                f"servos on {self.port_name} have different state-block layouts; "
                "one sync read needs one layout"
            )
        ((start, end, offsets),) = layouts
        self._block_start = start
        self._block_length = end - start
        self._offsets = dict(offsets)

    def _configure(self, servo: _Servo) -> None:
        """Return Delay Time 0, Status Return Level 2, watchdog; read what later calls rely on."""
        servo.torque_enabled = bool(self._read(servo, "Torque Enable", alerts="record"))
        servo.torque_wanted = servo.torque_enabled
        if self._read(servo, "Return Delay Time", alerts="record") != 0:
            if servo.torque_enabled:  # EEPROM is writable only with torque off
                self._write(servo, "Torque Enable", 0, alerts="ignore")
                servo.torque_enabled = False
            self._write(servo, "Return Delay Time", 0, alerts="record")
        if self._read(servo, "Status Return Level", alerts="record") != STATUS_RETURN_ALL:
            self._write(servo, "Status Return Level", STATUS_RETURN_ALL, alerts="record")
        servo.mode = self._read(servo, "Operating Mode", alerts="record")
        servo.min_position_raw = self._read(servo, "Min Position Limit", alerts="record")
        servo.max_position_raw = self._read(servo, "Max Position Limit", alerts="record")
        if _field(servo.table, "Current Limit") is not None:
            servo.current_limit_raw = self._read(servo, "Current Limit", alerts="record")
        if _field(servo.table, "Goal Current") is not None:
            servo.goal_current_raw = self._read(servo, "Goal Current", alerts="record")
        servo.profile_velocity_raw = self._read(servo, "Profile Velocity", alerts="record")
        servo.profile_acceleration_raw = self._read(servo, "Profile Acceleration", alerts="record")
        self._apply_watchdog(servo)
        servo.hardware_error = self._read(servo, "Hardware Error Status", alerts="ignore")

    def _apply_watchdog(self, servo: _Servo) -> None:
        if _field(servo.table, "Bus Watchdog") is None:
            return
        # Writing 0 clears a tripped watchdog (it reads -1 after tripping), then arm it if asked.
        self._write(servo, "Bus Watchdog", 0, alerts="record")
        if self._bus_watchdog_ms > 0:
            ticks = max(1, math.ceil(self._bus_watchdog_ms / ct.BUS_WATCHDOG_UNIT_MS))
            self._write(servo, "Bus Watchdog", ticks, alerts="record")

    # ------------------------------------------------------------------ reads

    def read_states(self) -> dict[int, ServoState]:
        """Read position, velocity, current and the moving flag of every servo in one transaction.

        A servo whose status packet carries the Alert bit gets its Hardware Error Status read and
        reported in `ServoState.hardware_error` (non-zero); use `raise_for_hardware_errors` to
        turn that into `HardwareFault`. XL430 servos report no current: `current_a` is NaN.
        """
        self._require_connected()
        try:
            errs_and_data = self._link.sync_read(
                self._block_start,
                self._block_length,
                self._state_ids,
                fast=self._use_fast_read,
                what="the servo state",
            )
        except (RigTimeoutError, CommunicationError) as exc:
            if isinstance(exc, InstructionRejected):
                raise
            silent = [self._servos[i].label for i in self._link.unanswered(self._servos)]
            if not silent:
                raise
            # A silent servo garbles a fast sync read (COMM_RX_CORRUPT); the cause is a timeout.
            raise RigTimeoutError(f"{exc}; not answering a ping: {', '.join(silent)}") from exc
        self._check_watchdogs_after_quiet()
        time_ns = self._clock.time_ns()
        off = self._offsets
        o_moving = off["Moving"]
        o_velocity = off["Present Velocity"]
        o_position = off["Present Position"]
        states: dict[int, ServoState] = {}
        for servo_id, (err, data) in errs_and_data.items():
            servo = self._servos[servo_id]
            if err & ALERT_BIT:
                self._link.stats.alerts += 1
                servo.hardware_error = self._read(servo, "Hardware Error Status", alerts="ignore")
                if servo.hardware_error:
                    servo.torque_enabled = False  # a latched error drops torque
            else:
                servo.hardware_error = 0
            o_current = servo.current_offset
            current_a = (
                int.from_bytes(data[o_current : o_current + 2], "little", signed=True) * units.CURRENT_UNIT_A
                if o_current is not None
                else math.nan
            )
            states[servo_id] = ServoState(
                servo_id=servo_id,
                position_rad=int.from_bytes(data[o_position : o_position + 4], "little", signed=True)
                * units.RAD_PER_PULSE,
                velocity_rad_s=int.from_bytes(data[o_velocity : o_velocity + 4], "little", signed=True)
                * units.RAD_S_PER_VELOCITY_UNIT,
                current_a=current_a,
                hardware_error=servo.hardware_error,
                moving=bool(data[o_moving]),
                time_ns=time_ns,
            )
        return states

    def _check_watchdogs_after_quiet(self) -> None:
        """After a quiet bus, read every servo's Bus Watchdog (98); clear and re-arm a tripped one.

        A trip needs the servo to hear nothing for the whole window; the host's clock measures
        the quiet from the last answer it had, and checks from 80 % of the window on (the two
        clocks need not agree). A healthy run reads in every control period and never checks.
        """
        now_ns = self._clock.monotonic_ns()
        last, self._last_answer_ns = self._last_answer_ns, now_ns
        if self._bus_watchdog_ms <= 0 or last is None:
            return
        quiet_ns = now_ns - last
        if quiet_ns < 0.8 * self._bus_watchdog_ms * 1e6:
            return
        for servo in self._servos.values():
            if _field(servo.table, "Bus Watchdog") is None or not servo.torque_enabled:
                continue  # only monitored while torque is on
            if self._read(servo, "Bus Watchdog", alerts="record") != ct.BUS_WATCHDOG_TRIPPED:
                continue
            self._apply_watchdog(servo)
            self._link.stats.watchdog_trips += 1
            self._watchdog_trips.append(WatchdogTrip(servo.spec.servo_id, servo.spec.role, quiet_ns / 1e9))

    def take_watchdog_trips(self) -> list[WatchdogTrip]:
        """The Bus Watchdog trips found (and cleared) since the last call; the caller logs them."""
        trips, self._watchdog_trips = self._watchdog_trips, []
        return trips

    def raise_for_hardware_errors(self, states: Mapping[int, ServoState]) -> None:
        """Raise `ServoHardwareFault` for the first state with a non-zero hardware error."""
        for servo_id, state in states.items():
            if state.hardware_error:
                role = self._servos[servo_id].spec.role if servo_id in self._servos else None
                raise hardware_fault(servo_id, role, state.hardware_error, "state read")

    def read_health(self) -> dict[int, ServoHealthReport]:
        """Input voltage, temperature and Hardware Error Status of every servo (unicast reads)."""
        self._require_connected()
        health: dict[int, ServoHealthReport] = {}
        for servo_id, servo in self._servos.items():
            voltage = self._read(servo, "Present Input Voltage", alerts="record")
            temperature = self._read(servo, "Present Temperature", alerts="record")
            servo.hardware_error = self._read(servo, "Hardware Error Status", alerts="ignore")
            health[servo_id] = ServoHealthReport(
                servo_id=servo_id,
                input_voltage_v=units.voltage_v_from_units(voltage),
                temperature_c=float(temperature),
                hardware_error=servo.hardware_error,
                time_ns=self._clock.time_ns(),
            )
        return health

    def read_hardware_error(self, servo_id: int) -> int:
        """Hardware Error Status (70) of one servo: raw bits, 0 = healthy."""
        self._require_connected()
        servo = self._servo(servo_id)
        servo.hardware_error = self._read(servo, "Hardware Error Status", alerts="ignore")
        return servo.hardware_error

    # ------------------------------------------------------------------ writes

    def write_goal_positions(self, goals_rad: Mapping[int, float]) -> None:
        """Sync-write goal positions in rad (0 rad = pulse 0; multi-turn in modes 4 and 5).

        Checked before anything is sent: the servo must be in a position mode, and the goal within
        Min/Max Position Limit (mode 3) or +-256 rev (modes 4 and 5); else `LimitError`.
        """
        self._require_connected()
        raw: dict[int, int] = {}
        for servo_id, goal_rad in goals_rad.items():
            servo = self._servo(servo_id)
            if not math.isfinite(goal_rad):
                raise LimitError(f"{servo.label}: goal position {goal_rad} rad is not a finite number")
            pulses = units.pulses_from_position_rad(goal_rad)
            if servo.mode == OperatingMode.POSITION:
                low, high = servo.min_position_raw, servo.max_position_raw
            elif servo.mode in POSITION_MODES:
                low, high = -ct.GOAL_POSITION_LIMIT_PULSES, ct.GOAL_POSITION_LIMIT_PULSES
            else:
                raise LimitError(
                    f"{servo.label} is in {OperatingMode(servo.mode).name} mode; "
                    "goal positions need mode 3, 4 or 5"
                )
            if not low <= pulses <= high:
                raise LimitError(
                    f"{servo.label}: goal position {goal_rad:.4f} rad is outside "
                    f"[{low * units.RAD_PER_PULSE:.4f}, {high * units.RAD_PER_PULSE:.4f}] rad "
                    f"in {OperatingMode(servo.mode).name} mode"
                )
            raw[servo_id] = pulses
        self._sync_write("Goal Position", raw)

    def write_goal_currents(self, goals_a: Mapping[int, float]) -> None:
        """Sync-write goal currents in A; within +-Current Limit (else `LimitError`, nothing sent)."""
        self._require_connected()
        raw: dict[int, int] = {}
        for servo_id, goal_a in goals_a.items():
            servo = self._servo(servo_id)
            raw[servo_id] = self._goal_current_units(servo, goal_a)
        self._sync_write("Goal Current", raw)
        for servo_id, value in raw.items():
            self._servos[servo_id].goal_current_raw = value

    def _goal_current_units(self, servo: _Servo, goal_a: float) -> int:
        if servo.current_limit_raw is None or _field(servo.table, "Goal Current") is None:
            raise LimitError(f"{servo.label}: model {servo.table.model_name} has no current control")
        if not math.isfinite(goal_a):
            raise LimitError(f"{servo.label}: goal current {goal_a} A is not a finite number")
        value = units.current_units_from_a(goal_a)
        limit = servo.current_limit_raw
        if abs(value) > limit:
            raise LimitError(
                f"{servo.label}: goal current {goal_a:.3f} A is outside "
                f"+-{limit * units.CURRENT_UNIT_A:.3f} A "
                "(Current Limit)"
            )
        return value

    def _sync_write(self, name: str, values: Mapping[int, int]) -> None:
        if not values:
            return
        field = _require(self._servo(next(iter(values))).table, name)
        param: list[int] = []
        for servo_id, value in values.items():
            param.append(servo_id)
            param.extend(units.to_le_bytes(value, field.size))
        self._link.sync_write(field.address, field.size, param, name)

    def set_torque(self, servo_ids: Sequence[int], enabled: bool) -> None:
        """Enable or disable torque, one confirmed write per servo.

        Enabling a servo with a latched hardware error raises `ServoHardwareFault`; reboot it first.
        """
        self._require_connected()
        for servo_id in servo_ids:
            servo = self._servo(servo_id)
            servo.torque_wanted = enabled
            self._write(servo, "Torque Enable", int(enabled), alerts="raise" if enabled else "ignore")
            servo.torque_enabled = enabled

    def set_operating_mode(
        self,
        servo_id: int,
        mode: OperatingMode,
        *,
        goal_current_a: float | None = None,
        profile_velocity_rad_s: float | None = None,
        profile_acceleration_rad_s2: float | None = None,
    ) -> None:
        """Switch the operating mode with torque off, then re-write goal current and profile.

        A mode change resets Goal Current to Current Limit and the profile to 0 on the servo, so
        both are written again after every switch: the values given here, else the ones in force
        before. In position modes the goal is set to the present position before torque is
        restored, so the servo does not jump. Torque ends as it was before the call.
        """
        self._require_connected()
        servo = self._servo(servo_id)
        mode = OperatingMode(mode)
        allowed = self._allowed_modes(servo)
        if int(mode) not in allowed:
            raise LimitError(
                f"{servo.label}: operating mode {int(mode)} ({mode.name}) is not available on "
                f"{servo.table.model_name}; allowed: {sorted(allowed)}"
            )
        goal_current_raw = servo.goal_current_raw
        if goal_current_a is not None:
            goal_current_raw = self._goal_current_units(servo, goal_current_a)
        profile_velocity_raw, profile_acceleration_raw = self._profile_units(
            servo, profile_velocity_rad_s, profile_acceleration_rad_s2
        )
        torque_was_on = servo.torque_enabled
        if torque_was_on:
            self._write(servo, "Torque Enable", 0, alerts="ignore")
            servo.torque_enabled = False
        self._write(servo, "Operating Mode", int(mode))
        servo.mode = int(mode)
        self._write_ram_settings(servo, goal_current_raw, profile_velocity_raw, profile_acceleration_raw)
        if torque_was_on:
            self._torque_on_in_place(servo)

    def set_profile(
        self, servo_id: int, velocity_rad_s: float | None = None, acceleration_rad_s2: float | None = None
    ) -> None:
        """Write Profile Velocity / Acceleration (0 = unlimited); None keeps the current value."""
        self._require_connected()
        servo = self._servo(servo_id)
        velocity_raw, acceleration_raw = self._profile_units(servo, velocity_rad_s, acceleration_rad_s2)
        # Only what was given is written (the runner calls this per ramp step).
        if acceleration_rad_s2 is not None:
            self._write(servo, "Profile Acceleration", acceleration_raw)
            servo.profile_acceleration_raw = acceleration_raw
        if velocity_rad_s is not None:
            self._write(servo, "Profile Velocity", velocity_raw)
            servo.profile_velocity_raw = velocity_raw

    def set_current_limit(self, servo_id: int, current_limit_a: float) -> None:
        """Write Current Limit (EEPROM: torque is turned off for the write and restored after)."""
        self._require_connected()
        servo = self._servo(servo_id)
        field = _field(servo.table, "Current Limit")
        if field is None:
            raise LimitError(f"{servo.label}: model {servo.table.model_name} has no Current Limit")
        value = units.current_units_from_a(current_limit_a)
        if not field.min <= value <= field.max:
            raise LimitError(
                f"{servo.label}: current limit {current_limit_a:.3f} A is outside "
                f"[{field.min * units.CURRENT_UNIT_A:.3f}, {field.max * units.CURRENT_UNIT_A:.3f}] A"
            )
        torque_was_on = servo.torque_enabled
        if torque_was_on:
            self._write(servo, "Torque Enable", 0, alerts="ignore")
            servo.torque_enabled = False
        self._write(servo, "Current Limit", value)
        servo.current_limit_raw = value
        if servo.goal_current_raw is not None and abs(servo.goal_current_raw) > value:
            servo.goal_current_raw = value if servo.goal_current_raw > 0 else -value
            self._write(servo, "Goal Current", servo.goal_current_raw)
        if torque_was_on:
            self._torque_on_in_place(servo)

    def _allowed_modes(self, servo: _Servo) -> set[int]:
        return set(servo.table.operating_modes)

    def _profile_units(
        self, servo: _Servo, velocity_rad_s: float | None, acceleration_rad_s2: float | None
    ) -> tuple[int, int]:
        velocity_raw = servo.profile_velocity_raw
        acceleration_raw = servo.profile_acceleration_raw
        if velocity_rad_s is not None:
            velocity_raw = self._checked_units(
                servo, "Profile Velocity", velocity_rad_s, units.velocity_units_from_rad_s, "rad/s"
            )
        if acceleration_rad_s2 is not None:
            acceleration_raw = self._checked_units(
                servo,
                "Profile Acceleration",
                acceleration_rad_s2,
                units.acceleration_units_from_rad_s2,
                "rad/s^2",
            )
        return velocity_raw, acceleration_raw

    def _checked_units(
        self, servo: _Servo, name: str, value: float, convert: Callable[[float], int], unit: str
    ) -> int:
        field = _require(servo.table, name)
        if not math.isfinite(value) or value < 0:
            raise LimitError(f"{servo.label}: {name.lower()} {value} {unit} must be >= 0 and finite")
        raw = convert(value)
        if not field.min <= raw <= field.max:
            raise LimitError(
                f"{servo.label}: {name.lower()} {value} {unit} is {raw} units; "
                f"allowed {field.min}-{field.max}"
            )
        return raw

    def _write_ram_settings(
        self,
        servo: _Servo,
        goal_current_raw: int | None,
        profile_velocity_raw: int,
        profile_acceleration_raw: int,
    ) -> None:
        if goal_current_raw is not None and _field(servo.table, "Goal Current") is not None:
            self._write(servo, "Goal Current", goal_current_raw)
            servo.goal_current_raw = goal_current_raw
        self._write(servo, "Profile Acceleration", profile_acceleration_raw)
        servo.profile_acceleration_raw = profile_acceleration_raw
        self._write(servo, "Profile Velocity", profile_velocity_raw)
        servo.profile_velocity_raw = profile_velocity_raw

    def _torque_on_in_place(self, servo: _Servo) -> None:
        """Torque on without a jump: in position modes the goal becomes the present position first."""
        if servo.mode in POSITION_MODES:
            self._write(servo, "Goal Position", self._read(servo, "Present Position"))
        self._write(servo, "Torque Enable", 1)
        servo.torque_enabled = True

    # ------------------------------------------------------------------ recovery

    def reboot(self, servo_id: int) -> None:
        """Reboot one servo to clear a latched hardware error, then restore its RAM settings.

        Polls with pings for up to `reboot_timeout_s`, requires Hardware Error Status 0, then
        re-applies Status Return Level, bus watchdog, goal current, profile and torque as they
        were. The multi-turn count is lost on a reboot: re-home in modes 4 and 5.

        Raises:
            ServoHardwareFault: the reboot budget of this run is spent, or the error is still latched.
            RigTimeoutError: the servo did not answer within `reboot_timeout_s`.
        """
        self._require_connected()
        servo = self._servo(servo_id)
        if self._reboots_done >= self._max_reboots:
            raise ServoHardwareFault(
                f"refusing to reboot {servo.label}: {self._reboots_done} reboot(s) already done this run "
                f"(limit {self._max_reboots}); inspect the rig before restarting",
                servo_id,
                servo.spec.role,
                servo.hardware_error,
            )
        self._reboots_done += 1
        self._link.stats.reboots += 1
        want_torque = servo.torque_wanted
        self._link.send_reboot(servo_id)  # one try; the ping poll below finds out either way
        self._wait_for_boot(servo)
        bits = self._read(servo, "Hardware Error Status", alerts="ignore")
        servo.hardware_error = bits
        if bits:
            raise hardware_fault(servo_id, servo.spec.role, bits, "reboot (still latched after the reboot)")
        servo.torque_enabled = False
        if self._read(servo, "Status Return Level") != STATUS_RETURN_ALL:
            self._write(servo, "Status Return Level", STATUS_RETURN_ALL)
        self._apply_watchdog(servo)
        servo.mode = self._read(servo, "Operating Mode")
        self._write_ram_settings(
            servo, servo.goal_current_raw, servo.profile_velocity_raw, servo.profile_acceleration_raw
        )
        if want_torque:
            self._torque_on_in_place(servo)

    def _wait_for_boot(self, servo: _Servo) -> None:
        poll_s = 0.05
        deadline_ns = self._clock.monotonic_ns() + round(self._reboot_timeout_s * 1e9)
        max_polls = math.ceil(self._reboot_timeout_s / poll_s) + 1  # bound even if the clock stalls
        for _ in range(max_polls):
            self._clock.sleep(poll_s)
            if self._link.ping_once(servo.spec.servo_id) == COMM_SUCCESS:
                return
            if self._clock.monotonic_ns() >= deadline_ns:
                break
        self._link.stats.failures += 1
        raise RigTimeoutError(
            f"{servo.label} did not answer a ping within {self._reboot_timeout_s:g} s after its reboot"
        )

    # ------------------------------------------------------------------ shutdown

    def shutdown(self, release: Callable[[], None] | None = None) -> None:
        """Make the rig safe and close: `release()`, then torque off every servo, then close the port.

        Keeps going when a step fails (every servo gets its torque-off attempt), defers Ctrl-C while
        torquing off, and re-raises the first error (later ones are attached as notes).
        Idempotent: a second call does nothing. Unlike every other method it may also run while a
        transaction was cut short (e.g. from a signal handler): making the rig safe comes first,
        and the SDK clears the input buffer before each instruction anyway.
        """
        if self._shut_down:
            return
        self._shut_down = True
        errors: list[BaseException] = []
        if release is not None:
            try:
                release()
            except BaseException as exc:
                errors.append(exc)
        with signals_deferred(signal.SIGINT) as interrupted:
            if self._link.has_port:
                self._link.abandon_transaction()  # one cut short by an exception must not block this
                errors.extend(self._torque_off_all())
            self._link.close_quietly(errors)
        self._connected = False
        if interrupted:
            errors.append(KeyboardInterrupt())
        if errors:
            first = errors[0]
            for other in errors[1:]:
                first.add_note(f"also during servo shutdown: {type(other).__name__}: {other}")
            raise first

    def _torque_off_all(self) -> list[BaseException]:
        errors: list[BaseException] = []
        if not self._connected:
            return errors
        # One broadcast packet reaches every servo at once; the confirmed writes below report per servo.
        with contextlib.suppress(Exception):
            self._sync_write("Torque Enable", dict.fromkeys(self._servos, 0))
        for servo in self._servos.values():
            servo.torque_wanted = False
            try:
                self._write(servo, "Torque Enable", 0, alerts="ignore")
                servo.torque_enabled = False
            except Exception as exc:
                errors.append(exc)
        return errors

    # ------------------------------------------------------------------ field access

    def _servo(self, servo_id: int) -> _Servo:
        try:
            return self._servos[servo_id]
        except KeyError:
            raise InputError(
                f"servo id {servo_id} is not configured; configured: {list(self._servos)}"
            ) from None

    def _require_connected(self) -> None:
        if not self._connected:
            state = "shut down" if self._shut_down else "not connected"
            raise NotConnectedError(f"servo bus on {self.port_name} is {state}")

    def _handle_alert(self, servo: _Servo, err: int, alerts: str, context: str) -> None:
        if not err & ALERT_BIT:
            return
        self._link.stats.alerts += 1
        if alerts == "ignore":
            return
        bits = self._read(servo, "Hardware Error Status", alerts="ignore")
        servo.hardware_error = bits
        if bits:
            servo.torque_enabled = False
        if alerts == "raise" and bits:
            raise hardware_fault(servo.spec.servo_id, servo.spec.role, bits, context)

    def _read(self, servo: _Servo, name: str, *, alerts: str = "raise") -> int:
        """Read one named field (signed fields decoded); check the Alert bit per `alerts`."""
        field = _require(servo.table, name)
        value, err = self._link.read(
            servo.spec.servo_id, field.address, field.size, field.signed, f"read of {name} from {servo.label}"
        )
        self._after_reply(servo, err, alerts, f"read of {name}")
        return value

    def _write(self, servo: _Servo, name: str, value: int, *, alerts: str = "raise") -> None:
        """Write one named field and wait for the servo's status (confirmed write)."""
        field = _require(servo.table, name)
        data = units.to_le_bytes(value, field.size)
        err = self._link.write(
            servo.spec.servo_id, field.address, data, f"write of {name}={value} to {servo.label}"
        )
        self._after_reply(servo, err, alerts, f"write of {name}={value}")

    def _after_reply(self, servo: _Servo, err: int, alerts: str, context: str) -> None:
        """Alert bit first (a faulted servo refuses torque with Result Fail), then the error number."""
        self._handle_alert(servo, err, alerts, context)
        number = err & ERROR_NUMBER_MASK
        if number:
            self._link.stats.failures += 1
            raise InstructionRejected(
                f"{servo.label} rejected the {context}: {error_number_name(err)}", servo.spec.servo_id, number
            )


__all__ = ["DynamixelServoBus", "ServoHealthReport", "ServoInfo", "ServoSpecLike", "WatchdogTrip"]
