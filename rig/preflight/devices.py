"""The devices `rig check` talks to, from a rig config: real ports, or the simulated rig's emulators.

A hardware config gets the same drivers a run uses, on its ports, except that a missing or unusable
calibration file is a finding (the line section says so), not a refusal. A simulated config gets the
simulated rig's session (its emulators behind the real drivers, in virtual time), whose cell has its
nominal calibration.
"""

from __future__ import annotations

from rig.errors import InputError
from rig.hw.clock import SystemClock
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.loadcell.calibration import Calibration
from rig.hw.loadcell.driver import SerialLoadCell
from rig.preflight.context import CheckDevices
from rig.rig_config import RigConfig
from rig.rigs import open_check_session
from rig.vocabulary import RigKind


def check_devices(config: RigConfig, *, seed: int = 0) -> CheckDevices:
    """The devices of `config`, nothing opened yet."""
    if config.kind == RigKind.SIMULATED:
        session = open_check_session(config, seed=seed)
        if not isinstance(session.servos, DynamixelServoBus):
            raise TypeError("the simulated rig's servos are not a DynamixelServoBus")
        return CheckDevices(session.servos, session.load_cell, session.clock, calibrated=True)
    clock = SystemClock()
    calibration, problem = _calibration(config)
    servos = DynamixelServoBus(
        config.servos.port,
        config.servos.baud,
        config.servos.servos,
        clock,
        retries=config.servos.retries,
        bus_watchdog_ms=config.servos.watchdog_ms,
    )
    load_cell = SerialLoadCell(
        config.loadcell.port,
        baud=config.loadcell.baud,
        format_name=config.loadcell.format,
        calibration=calibration,
        stale_timeout_s=config.limits.stale_timeout_s,
        clock=clock,
        rate_hz=config.loadcell.rate_hz,
        boot_grace_s=config.loadcell.boot_grace_s,
    )
    return CheckDevices(
        servos, load_cell, clock, calibrated=calibration is not None, calibration_problem=problem
    )


def _calibration(config: RigConfig) -> tuple[Calibration | None, str]:
    path = config.loadcell.calibration_path
    if path is None:
        return None, "loadcell.calibration is not set"
    try:
        return Calibration.load(path), ""
    except InputError as exc:
        return None, str(exc)
