"""What every pre-flight section is given: the rig config, the options, and the devices, opened once.

Sections ask for the servo bus or the load cell through `CheckContext`; the first to ask opens it,
and `close()` turns every servo's torque off and closes both. A device that cannot be opened is
remembered as the reason, so each later section reports it once instead of retrying.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from rig.errors import HandshakeError, RigError
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.seams import Clock, LoadCell, LoadCellSample
from rig.hw.usb_latency import DEFAULT_SYSFS_ROOT
from rig.inputs.protocol import Protocol
from rig.inputs.rig_config import RigConfig

LISTEN_POLL_S = 0.02  # how often the listening window drains the load cell (the runner's tick)


@dataclass(frozen=True)
class CheckOptions:
    """The command's options that change what the sections do."""

    move: bool = False  # the jog (direction, stiffness) may move the winch
    sysfs_root: Path = DEFAULT_SYSFS_ROOT  # where the USB-serial latency timers are read
    protocols: tuple[Protocol, ...] = ()  # protocols whose ceilings are checked against the rig's
    loadcell_window_s: float = 5.0  # how long the load cell is listened to (after its first sample)
    jog_travel_rev: float = 1.0  # the most the jog turns the winch each way


@dataclass(frozen=True)
class JogFindings:
    """What `rig check --move` found: the reel-in direction (None: neither way) and the line stiffness."""

    reel_direction: int | None
    stiffness_n_per_m: float | None


@dataclass
class CheckDevices:
    """The devices a check talks to: the real drivers, on hardware ports or on the simulator's emulators."""

    servos: DynamixelServoBus
    load_cell: LoadCell
    clock: Clock
    calibrated: bool  # the cell's forces are in newtons (a calibration is loaded)
    calibration_problem: str = ""  # why there is none


@dataclass
class CheckContext:
    """One `rig check` invocation: config, options, and the devices opened on demand."""

    config: RigConfig
    options: CheckOptions
    make_devices: Callable[[], CheckDevices]
    devices: CheckDevices | None = None
    servos_connected: bool = False
    servo_failure: str | None = None  # why the bus could not be connected, once it was tried
    servo_handshake: HandshakeError | None = None  # servos missing or not as configured
    cell_open: bool = False
    cell_failure: str | None = None
    jog_findings: JogFindings | None = None  # set by the move section
    listened: list[LoadCellSample] | None = None  # what the load cell sent in the listening window
    listened_s: float = 0.0  # how long the window lasted, on the devices' clock

    def cell_samples(self) -> list[LoadCellSample] | None:
        """The load cell's samples over `options.loadcell_window_s` (listened to once), or None.

        None when the cell could not be opened or went silent (`cell_failure` says why).
        """
        if self.listened is not None:
            return self.listened
        if self.cell_failure is not None:
            return None
        cell = self.load_cell()
        if cell is None:
            return None
        clock = self.clock
        samples: list[LoadCellSample] = []
        start_ns = clock.monotonic_ns()
        end_ns = start_ns + round(self.options.loadcell_window_s * 1e9)
        try:
            cell.poll()  # what arrived before the window does not count
            while clock.monotonic_ns() < end_ns:
                clock.sleep(LISTEN_POLL_S)
                samples += cell.poll()
        except (RigError, OSError) as exc:
            self.cell_failure = f"{type(exc).__name__}: {exc}"
            return None
        self.listened = samples
        self.listened_s = (clock.monotonic_ns() - start_ns) / 1e9
        return samples

    def _devices(self) -> CheckDevices:
        if self.devices is None:
            self.devices = self.make_devices()
        return self.devices

    def servo_bus(self) -> DynamixelServoBus | None:
        """The connected bus, or None (then `servo_failure` says why)."""
        if self.servos_connected:
            return self._devices().servos
        if self.servo_failure is not None:
            return None
        try:
            bus = self._devices().servos
            bus.connect()
        except (RigError, OSError) as exc:
            self.servo_failure = f"{type(exc).__name__}: {exc}"
            self.servo_handshake = exc if isinstance(exc, HandshakeError) else None
            return None
        self.servos_connected = True
        return bus

    def load_cell(self) -> LoadCell | None:
        """The open load cell, or None (then `cell_failure` says why)."""
        if self.cell_open:
            return self._devices().load_cell
        if self.cell_failure is not None:
            return None
        try:
            cell = self._devices().load_cell
            cell.open()
        except (RigError, OSError) as exc:
            self.cell_failure = f"{type(exc).__name__}: {exc}"
            return None
        self.cell_open = True
        return cell

    @property
    def clock(self) -> Clock:
        """The devices' clock (virtual on the simulated rig)."""
        return self._devices().clock

    @property
    def calibrated(self) -> bool:
        """Whether the load cell reports newtons."""
        return self._devices().calibrated

    def close(self, release: Callable[[], None] | None = None) -> None:
        """Run `release` (if the bus is connected), torque every servo off, close the load cell."""
        if self.devices is None:
            return
        try:
            if self.servos_connected:
                self.devices.servos.shutdown(release)
        finally:
            if self.cell_open:
                with contextlib.suppress(RigError, OSError):
                    self.devices.load_cell.close()
            self.servos_connected = False
            self.cell_open = False
