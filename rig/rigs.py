"""Composition: the rig a prepared run asks for, hardware or simulated (the CLI, tests and benchmarks use it).

This is the one module that knows both rigs; the runner below it sees only `rig.hw.session.RigSession`
and, beside it, what `rig.runner.rig_to_run.RigToRun` says a composition may know of a rig.
"""

from __future__ import annotations

from typing import assert_never

from rig.hw.hardware_rig import hardware_session, rig_calibration
from rig.hw.session import RigSession
from rig.inputs.rig_config import RigConfig
from rig.runner.execute import PreparedRun
from rig.runner.rig_to_run import BareRig, RigToRun
from rig.sim.kinds import DeviceLevel
from rig.sim.simulated_rig import SimulatedRig, simulated_rig
from rig.vocabulary import RigKind

__all__ = [
    "check_session_inputs",
    "open_check_session",
    "open_rig",
    "open_simulated_rig",
]


def check_session_inputs(config: RigConfig) -> None:
    """Validate what opening a session reads besides the config (the calibration file); opens nothing."""
    rig_calibration(config)


def open_rig(prepared: PreparedRun, *, devices: DeviceLevel = DeviceLevel.BYTE) -> RigToRun:
    """The rig a prepared run asks for (nothing connected yet).

    A hardware config gives the hardware rig (always real time); a simulated one gives
    `open_simulated_rig` on `devices` ("byte": the real drivers on emulators; "object": the
    object-level devices, same world; ignored for hardware).
    """
    match prepared.config.kind:
        case RigKind.HARDWARE:
            return BareRig(hardware_session(prepared.config, sysfs_root=prepared.request.sysfs_root))
        case RigKind.SIMULATED:
            check_session_inputs(prepared.config)
            return open_simulated_rig(prepared, devices=devices)
        case kind:
            assert_never(kind)


def open_check_session(config: RigConfig, *, seed: int = 0) -> RigSession:
    """A simulated config's session for `rig check` (seeded, virtual time; no run around it)."""
    return simulated_rig(config, seed=seed).session


def open_simulated_rig(prepared: PreparedRun, *, devices: DeviceLevel = DeviceLevel.BYTE) -> SimulatedRig:
    """The simulated rig of a prepared run, seeded from its journal so a resumed part draws the same world.

    Each part starts its virtual clock after the previous one's (`invocation`), and
    `request.realtime` paces it by the wall clock.
    """
    return simulated_rig(
        prepared.config,
        seed=prepared.journal.seed,
        realtime=prepared.request.realtime,
        invocation=prepared.journal.invocations + 1,
        devices=devices,
    )
