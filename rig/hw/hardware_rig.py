"""The hardware rig: a `RigSession` on real serial ports, a person at the console, forks or hand bending.

Nothing is opened here; the runner connects inside its safety `try`, so a failure while
connecting still ends in the safe state.
"""

from __future__ import annotations

import select
import sys
from collections.abc import Callable
from pathlib import Path

from rig.errors import InputError
from rig.hw.bending import config_fixture
from rig.hw.clock import SystemClock
from rig.hw.configuration.factory import hardware_configuration_source
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.loadcell.calibration import Calibration
from rig.hw.loadcell.driver import SerialLoadCell
from rig.hw.seams import Clock
from rig.hw.session import OperatorRequest, RigSession
from rig.hw.usb_latency import DEFAULT_SYSFS_ROOT
from rig.inputs.rig_config import RigConfig, configuration_source_kind
from rig.vocabulary import RigKind


def rig_calibration(config: RigConfig) -> Calibration | None:
    """The load-cell calibration a rig config names, validated; None when it names none.

    A hardware rig needs one; a simulated rig keeps its cell's nominal calibration, but a file it
    names must still be a valid one (an unusable file is an input error whatever the rig).
    """
    cal_path = config.loadcell.calibration_path
    if cal_path is None:
        if config.kind == RigKind.HARDWARE:
            raise InputError(
                f"{config.source}: loadcell.calibration: a hardware rig needs a calibration file; "
                "make one with `rig calibrate`"
            )
        return None
    return Calibration.load(cal_path)


def config_servo_bus(
    config: RigConfig, clock: Clock, *, sysfs_root: Path = DEFAULT_SYSFS_ROOT
) -> DynamixelServoBus:
    """The servo bus a rig config names, on its port, not yet connected.

    `sysfs_root`: where its USB latency timer is read at connect (`rig run --sysfs-root`).
    """
    return DynamixelServoBus(
        config.servos.port,
        config.servos.baud,
        config.servos.servos,
        clock,
        retries=config.servos.retries,
        bus_watchdog_ms=config.servos.watchdog_ms,
        sysfs_root=sysfs_root,
    )


def config_load_cell(config: RigConfig, calibration: Calibration | None, clock: Clock) -> SerialLoadCell:
    """The load cell a rig config names, on its port, not yet opened (uncalibrated: raw counts)."""
    return SerialLoadCell(
        config.loadcell.port,
        baud=config.loadcell.baud,
        format_name=config.loadcell.format,
        calibration=calibration,
        stale_timeout_s=config.limits.stale_timeout_s,
        clock=clock,
        rate_hz=config.loadcell.rate_hz,
        boot_grace_s=config.loadcell.boot_grace_s,
    )


def hardware_session(config: RigConfig, *, sysfs_root: Path = DEFAULT_SYSFS_ROOT) -> RigSession:
    """A session on the serial ports named in a `kind: hardware` rig config.

    `sysfs_root`: where the servo port's USB latency timer is read at connect.
    """
    if config.kind != RigKind.HARDWARE:
        raise InputError(f"{config.source}: kind: expected hardware, got {config.kind}")
    calibration = rig_calibration(config)
    cal_path = config.loadcell.calibration_path
    assert calibration is not None and cal_path is not None  # a hardware rig needs both
    clock = SystemClock()
    servos = config_servo_bus(config, clock, sysfs_root=sysfs_root)
    load_cell = config_load_cell(config, calibration, clock)
    return RigSession(
        kind=RigKind.HARDWARE,
        clock=clock,
        servos=servos,
        load_cell=load_cell,
        operator=ConsoleOperator(),
        fixture=config_fixture(config),
        configuration=hardware_configuration_source(config, clock),
        configuration_kind=configuration_source_kind(config),
        winch_id=config.servos.winch.servo_id,
        roles={s.servo_id: s.role for s in config.servos.servos},
        attachments=[(cal_path.name, "application/json", cal_path.read_bytes())],
    )


class ConsoleOperator:
    """A person at the terminal: prompts on stderr, waits for Enter on stdin."""

    def confirm(self, request: OperatorRequest, keep_alive: Callable[[], None]) -> None:
        """Prompt, then keep the rig's control loop running until Enter; no terminal is an error."""
        text = request.text
        if not sys.stdin or not sys.stdin.isatty():
            raise InputError(
                f"operator step needs a person at a terminal (stdin is not one; over ssh use `ssh -t`, "
                f"best inside tmux or screen): {text}"
            )
        print(f"\n>>> {text}  [Enter to continue, Ctrl-C to abort] ", end="", file=sys.stderr, flush=True)
        while not select.select([sys.stdin], [], [], 0)[0]:
            keep_alive()
        sys.stdin.readline()
