"""The simulator's kinds: slips, the line's hook, device levels and the faults it can inject.

How a simulated joint slips, what the line is hooked to, which devices a run talks to, and the
faults a rig config's `simulation.faults:` (or `rig sim servos --fault`) injects. Only the
simulator, the composition and the CLI speak of these, so they sit under `rig.sim`, not in
`rig.vocabulary` (which the layers below the simulator share). As there, each value is the string
files, logs and JSON have always carried.
"""

from __future__ import annotations

from enum import StrEnum

__all__ = [
    "ArticleSetup",
    "DeviceLevel",
    "FaultDevice",
    "FaultKind",
    "HostFaultKind",
    "LoadCellFaultKind",
    "LoggerFaultKind",
    "ReplyFaultKind",
    "ServoFaultFlag",
    "ServoFaultKind",
    "SlipKind",
]


class SlipKind(StrEnum):
    """How a simulated joint slips (`simulation.slips.mix`; `rig.sim.settings.SlipKindMix` describes each).

    The order is that of the mix's probabilities.
    """

    SUDDEN = "sudden"
    SMALL_DROP = "small_drop"
    CREEP = "creep"
    STICK_SLIP = "stick_slip"
    OTHER_JOINT = "other_joint"
    NO_SLIP = "no_slip"


class ArticleSetup(StrEnum):
    """What the simulated winch line is hooked to: the whole link, or the single-joint specimen."""

    LINK = "link"
    SPECIMEN = "specimen"


class DeviceLevel(StrEnum):
    """The simulated devices a run talks to: the real drivers on byte-level emulators, or objects."""

    BYTE = "byte"
    OBJECT = "object"


class FaultDevice(StrEnum):
    """The simulated devices a rig config's `simulation.faults:` entry can name (`FaultConfig.device`)."""

    SERVOS = "servos"  # every servo on the bus
    WINCH = "winch"  # the servos of that role
    BENDER = "bender"
    LOADCELL = "loadcell"
    LOGGER = "logger"
    HOST = "host"


class ServoFaultKind(StrEnum):
    """The faults a simulated servo can be given (rate kinds are `ReplyFaultKind`'s; the rest are timed)."""

    DROP = "drop"
    CORRUPT = "corrupt"
    DELAY = "delay"
    SILENT = "silent"  # its replies are lost, it still obeys
    DISCONNECT = "disconnect"  # it neither hears nor answers
    OVERLOAD = "overload"  # Hardware Error Status 0x20 latches


class LoadCellFaultKind(StrEnum):
    """The faults a simulated load cell can be given (`garble`, `checksum` at a rate; the rest timed)."""

    GARBLE = "garble"
    CHECKSUM = "checksum"
    GAP = "gap"
    SILENT = "silent"
    DISCONNECT = "disconnect"


class LoggerFaultKind(StrEnum):
    """The faults the run log can be given."""

    WRITE_ERROR = "write_error"


class HostFaultKind(StrEnum):
    """The faults the simulated host can be given."""

    PAUSE = "pause"


# A `simulation.faults:` entry's kind: one of its device's kinds (`rig.sim.settings.FAULT_KINDS`).
FaultKind = ServoFaultKind | LoadCellFaultKind | LoggerFaultKind | HostFaultKind


class ReplyFaultKind(StrEnum):
    """What an emulated Dynamixel bus does to a reply it is told to fault (`rig.sim.dxl.faults`)."""

    DROP = "drop"
    CORRUPT = "corrupt"
    DELAY = "delay"


class ServoFaultFlag(StrEnum):
    """The fault kinds of `rig sim servos --fault KIND:...` (grammar in `rig.sim.dxl.faults`)."""

    DROP = "drop"
    CORRUPT = "corrupt"
    DELAY = "delay"
    SILENT = "silent"
    HWERROR = "hwerror"
    BAUD = "baud"
