"""The typed seams between the runner and the hardware.

The runner sees hardware only through these `typing.Protocol`s and value types. Real drivers
(dynamixel-sdk, pyserial) and simulated ones implement them; everything crossing them is in SI
units (rad, rad/s, A, N, s) with epoch-nanosecond timestamps.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import TYPE_CHECKING, NamedTuple, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from rig.hw.dxl.bus import WatchdogTrip
    from rig.hw.dxl.transport import BusStats  # the driver's counters (it imports this module)


class OperatingMode(IntEnum):
    """Dynamixel X-series Operating Mode (address 11)."""

    CURRENT = 0  # torque (current) control; no position loop
    VELOCITY = 1  # velocity control
    POSITION = 3  # position control within Min/Max Position Limit, one turn
    EXTENDED_POSITION = 4  # multi-turn position, +-256 rev
    CURRENT_BASED_POSITION = 5  # multi-turn position with current capped at Goal Current
    PWM = 16  # voltage (PWM) control


@dataclass(frozen=True, slots=True)
class ServoState:
    """One servo's state read in a single bus transaction, in SI units."""

    servo_id: int
    position_rad: float
    velocity_rad_s: float
    current_a: float
    hardware_error: int  # raw Hardware Error Status bits; 0 means healthy
    moving: bool
    time_ns: int  # epoch ns at which the read completed


class LoadCellSample(NamedTuple):
    """One load-cell reading: host receive time, the device's raw count and the calibrated force.

    A NamedTuple rather than a frozen dataclass like the other value types: a driver makes 1000 a
    second, and a frozen dataclass costs about four times as much to construct.
    """

    time_ns: int  # epoch ns of sampling: the device clock mapped onto the host's, else receipt time
    raw: int  # ADC counts as sent by the device (or the indicator's value in its least digit)
    force_n: float  # calibrated line tension
    seq: int | None = None  # device sequence counter, when the format has one
    device_time_us: int | None = None  # device clock, when the format has one


@dataclass(frozen=True, slots=True)
class ConfigurationReading:
    """A measured link configuration and, after a slip, the joint that moved (1-based) if known."""

    transforms: np.ndarray  # (J, 4, 4) pose of {i} in {i-1}, base to tip
    time_ns: int
    joint_angles_rad: tuple[float, ...] | None = None  # planar links only
    slipped_joint: int | None = None
    uncertainty_rad: tuple[float, ...] | None = None  # per-joint sd, where the source knows it


@runtime_checkable
class Clock(Protocol):
    """One clock for runner and world: real time on hardware, virtual time in simulation."""

    def monotonic_ns(self) -> int:
        """Nanoseconds on a clock that never goes backwards (for intervals and timeouts)."""
        ...

    def time_ns(self) -> int:
        """Epoch nanoseconds (for log times): the monotonic clock plus one anchor per run."""
        ...

    def sleep(self, seconds: float) -> None:
        """Wait; a virtual clock advances instead of waiting."""
        ...


@runtime_checkable
class ServoBus(Protocol):
    """A Dynamixel bus with one owner: connect, read state, command goals, shut down safely."""

    def connect(self) -> None:
        """Open the port, set the baud rate, and handshake every configured ID."""
        ...

    def read_states(self) -> dict[int, ServoState]:
        """Sync-read the state of every configured servo."""
        ...

    def set_operating_mode(
        self,
        servo_id: int,
        mode: OperatingMode,
        *,
        goal_current_a: float | None = None,
        profile_velocity_rad_s: float | None = None,
        profile_acceleration_rad_s2: float | None = None,
    ) -> None:
        """Switch mode (torque off while switching), then re-write goal current and profile."""
        ...

    def set_torque(self, servo_ids: Sequence[int], enabled: bool) -> None:
        """Enable or disable torque on the given servos."""
        ...

    def set_profile(
        self, servo_id: int, velocity_rad_s: float | None = None, acceleration_rad_s2: float | None = None
    ) -> None:
        """Write Profile Velocity / Acceleration (None keeps the value in force)."""
        ...

    def set_current_limit(self, servo_id: int, current_limit_a: float) -> None:
        """Write Current Limit (EEPROM: with torque off for the write)."""
        ...

    def write_goal_positions(self, goals_rad: Mapping[int, float]) -> None:
        """Sync-write goal positions (rad, multi-turn in modes 4 and 5)."""
        ...

    def write_goal_currents(self, goals_a: Mapping[int, float]) -> None:
        """Sync-write goal currents (A); in mode 5 this caps the torque."""
        ...

    def reboot(self, servo_id: int) -> None:
        """Reboot one servo to clear a latched hardware error; bounded and counted."""
        ...

    def shutdown(self, release: Callable[[], None] | None = None) -> None:
        """Run `release`, then torque off every servo, then close; re-raise the first error."""
        ...


@runtime_checkable
class LoadCell(Protocol):
    """A streaming load cell; `poll` never blocks."""

    def open(self) -> None:
        """Open the port and start receiving."""
        ...

    def poll(self) -> list[LoadCellSample]:
        """Return the samples received since the last call (possibly none); never blocks.

        Raises `rig.errors.StaleDataError` when no valid sample arrived for longer than the
        configured stale timeout.
        """
        ...

    def close(self) -> None:
        """Stop receiving and close the port."""
        ...


@dataclass(frozen=True, slots=True)
class LoadCellLineStats:
    """What a load cell's serial line delivered and lost since the port was opened (cumulative).

    For formats with a sequence counter (`rig-lc1`), `missing_samples` counts every sample whose
    line never became a sample: lost on the wire, garbled or failing its checksum (so it includes
    those two counts). Formats without one (`indicator-st`) only count garbled lines.
    """

    lines_ok: int  # valid lines, decoded into samples
    checksum_failures: int  # well-formed lines whose checksum did not match (discarded)
    garbled_lines: int  # malformed or truncated lines (discarded)
    missing_samples: int  # sequence numbers never received, summed over the gaps
    sequence_gaps: int  # places where the device's sequence counter skipped
    samples_dropped: int  # decoded samples discarded because poll() came too late (queue full)
    info_lines: int = 0  # information lines (rig-lc1 `#...`): what the device said, not damage
    restarts: int = 0  # the device restarted (a boot banner after a sample); samples were lost unseen

    def since(self, earlier: LoadCellLineStats) -> LoadCellLineStats:
        """The counts after `earlier` (e.g. one trial's); all of these if the port was reopened since."""
        pairs = [(getattr(self, f.name), getattr(earlier, f.name)) for f in fields(self)]
        if any(now < then for now, then in pairs):  # counters restart at open()
            return self
        return LoadCellLineStats(*(now - then for now, then in pairs))

    @property
    def lossless(self) -> bool:
        """Nothing was lost, garbled or dropped, and the device did not restart."""
        lost = self.checksum_failures + self.garbled_lines + self.missing_samples + self.samples_dropped
        return lost == 0 and self.restarts == 0

    def as_dict(self) -> dict[str, int]:
        """The counts by name (for JSON and log messages)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def describe(self) -> str:
        """One line for an operator, e.g. `1000 lines ok; 12 samples missing in 2 sequence gaps, ...`."""
        return (
            f"{self.lines_ok} lines ok; {self.missing_samples} samples missing in {self.sequence_gaps} "
            f"sequence gaps, {self.checksum_failures} checksum failures, {self.garbled_lines} garbled "
            f"lines, {self.samples_dropped} samples dropped (queue full)"
            + (f"; the device restarted {self.restarts} times" if self.restarts else "")
            + (f"; {self.info_lines} information lines" if self.info_lines else "")
        )


@runtime_checkable
class LineStatsSource(Protocol):
    """A load cell that counts its serial lines (optional beside `LoadCell`: check with isinstance)."""

    def line_stats(self) -> LoadCellLineStats:
        """The counts since the port was last opened (a snapshot; safe from any thread)."""
        ...


@runtime_checkable
class BusStatsSource(Protocol):
    """A servo bus that counts its exchanges (optional beside `ServoBus`: check with isinstance)."""

    @property
    def stats(self) -> BusStats:
        """A copy of the counters since the driver was made (retries, timeouts, corrupt replies, ...)."""
        ...


@runtime_checkable
class WatchdogTripSource(Protocol):
    """A servo bus that finds and clears Bus Watchdog trips mid-run (optional: check with isinstance)."""

    def take_watchdog_trips(self) -> list[WatchdogTrip]:
        """The trips found and cleared since the last call (each to be logged once)."""
        ...


@runtime_checkable
class PortLatencySource(Protocol):
    """A device whose USB-serial adapter's latency timer was read as its port opened (optional)."""

    @property
    def latency_timer_ms(self) -> int | None:
        """The timer in ms; None before connecting, or for a port without one (not FTDI, a pty, a URL)."""
        ...


@runtime_checkable
class ConfigurationSource(Protocol):
    """Where the measured link configuration comes from (simulator, file, operator, camera)."""

    def measure(self) -> ConfigurationReading:
        """Measure the current configuration (with the source's noise)."""
        ...


@dataclass(frozen=True, slots=True)
class MeasurementRequest:
    """What the runner tells a source before a measurement: which configuration, why, and a keep-alive.

    `keep_alive()` is one control period of the runner: a source that waits (for a person typing)
    calls it over and over, so the rig keeps being read and the servos keep hearing the host.
    """

    configuration_index: int | None  # 1-based index of the protocol's configuration; None outside one
    commanded_angles_rad: tuple[float, ...] | None
    after_slip: bool  # False: after bending; True: after a slip, to tell which joint moved
    keep_alive: Callable[[], None]


@runtime_checkable
class RequestAwareSource(Protocol):
    """A configuration source that needs to know what is being measured (file, operator): optional."""

    def prepare(self, request: MeasurementRequest) -> None:
        """Called before each `measure()`."""
        ...
