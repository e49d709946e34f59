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
from rig.hw.hardware_rig import config_load_cell, config_servo_bus
from rig.hw.loadcell.calibration import Calibration
from rig.inputs.rig_config import RigConfig
from rig.preflight.check_context import CheckDevices
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
    servos = config_servo_bus(config, clock)
    load_cell = config_load_cell(config, calibration, clock)
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
