"""The rig's vocabulary: every kind, role and name that more than one layer uses, defined once.

These enums sit at the bottom of the import layers (beside `rig.errors`), so that a protocol
parser, a device driver, the simulator, the runner and the log all speak of the same members.
Each value is the string (or number) that files, logs and JSON have always carried, so a
`StrEnum` member compares, hashes, formats and serialises exactly as that string does.

Code that does something per kind dispatches with `match` and `typing.assert_never`: mypy then
names every place a new member has to be handled (docs/extending.md lists them).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

# The detector's event kinds are the model's (model/ may not import rig): re-used, not restated.
from model.slip_detector import SlipEventKind


class TrialKind(StrEnum):
    """The two trial kinds of the paper: one joint loaded at a distance, or the whole link bent."""

    JOINT_ESTIMATION = "joint_estimation"  # V-A: a single joint, the load at a distance l
    LINK_VALIDATION = "link_validation"  # V-B: the bent link


class StepKind(StrEnum):
    """The steps a trial's template is made of (`steps:` of a protocol block)."""

    PROMPT = "prompt"
    TARE = "tare"
    BEND = "bend"
    MEASURE = "measure"
    RAMP_UNTIL_SLIP = "ramp_until_slip"
    UNLOAD = "unload"
    RESET = "reset"
    PAUSE = "pause"


class TrialOutcome(StrEnum):
    """How a trial ended.

    `slip` (a sudden drop), `creep` (the tension sagged) and `stick_slip` (further drops while the
    line re-tensioned) are slips of the joint under test: their peak is the slip load
    (`SLIP_LIKE`). `no_slip`: the force limit or the winch travel came first; the peak is a lower
    bound on the capacity. `other_joint`: the configuration source says another joint moved.
    `aborted`: a step timed out or a fault stopped the trial (`TrialResult.reason`). `fault` is read
    in logs and journals from before `aborted` took its place.
    """

    SLIP = "slip"
    CREEP = "creep"
    STICK_SLIP = "stick_slip"
    NO_SLIP = "no_slip"
    OTHER_JOINT = "other_joint"
    ABORTED = "aborted"
    FAULT = "fault"


# The outcomes whose peak is a slip load of the joint under test: the only ones the fit uses.
SLIP_LIKE = frozenset({TrialOutcome.SLIP, TrialOutcome.CREEP, TrialOutcome.STICK_SLIP})


class ServoRole(StrEnum):
    """What a servo does on the rig: the winch loads the line, a bender bends the link."""

    WINCH = "winch"
    BENDER = "bender"


class RigKind(StrEnum):
    """Which rig a config describes (`kind:` of a rig config)."""

    SIMULATED = "simulated"
    HARDWARE = "hardware"


class LoadCellFormatName(StrEnum):
    """The load cell's line formats (protocols/loadcell-formats.md; codecs in rig.hw.loadcell.formats)."""

    RIG_LC1 = "rig-lc1"
    INDICATOR_ST = "indicator-st"
    VALUE_UNIT = "value-unit"


UART_BITS_PER_BYTE = 10  # 8N1: start bit, 8 data bits, stop bit


@dataclass(frozen=True, slots=True)
class LoadCellFormatTraits:
    """What every layer needs to know of a load-cell format besides its codec.

    The rig config checks the baud rate against the rate with it, the driver polls with it, the
    emulator answers polls with it, and the codec (rig.hw.loadcell.formats) takes its longest line
    from it, so that each fact is stated here once.
    """

    max_line_bytes: int  # the longest valid line, terminator included
    poll_command: bytes | None = None  # a polled device answers one line per command; None: it streams

    def max_rate_hz(self, baud: int) -> float:
        """The most lines per second `baud` carries, every line the longest (8N1, no gaps)."""
        return baud / (UART_BITS_PER_BYTE * self.max_line_bytes)


# One entry per format (tests/test_loadcell_formats.py checks that every member has one).
LOADCELL_FORMAT_TRAITS: dict[LoadCellFormatName, LoadCellFormatTraits] = {
    LoadCellFormatName.RIG_LC1: LoadCellFormatTraits(len(b"$LC,65535,4294967295,-2147483648*FF\r\n")),
    LoadCellFormatName.INDICATOR_ST: LoadCellFormatTraits(len(b"ST,GS,+0001.23kg\r\n") + 1),
    # `-12345.678 lbF` CR LF: sign, up to 9 characters of digits and point, space, 3-letter unit.
    LoadCellFormatName.VALUE_UNIT: LoadCellFormatTraits(len(b"-12345.678 kgf\r\n"), poll_command=b"?\r"),
}


class ServoModel(StrEnum):
    """The Dynamixel models the rig supports (Protocol 2.0 firmware): the name as ROBOTIS writes it.

    Their facts (model number, current sensing, stall point, voltage range) are data in
    `rig.inputs.servo_ratings`; their control tables are built in `rig.hw.dxl.control_table`.
    """

    XM430_W350 = "XM430-W350"
    XL430_W250 = "XL430-W250"
    XM430_W210 = "XM430-W210"
    XH430_W210 = "XH430-W210"
    XH430_W350 = "XH430-W350"
    XM540_W150 = "XM540-W150"
    XM540_W270 = "XM540-W270"
    XH540_W150 = "XH540-W150"
    XH540_W270 = "XH540-W270"
    XW540_T140 = "XW540-T140"
    TWO_XL430_W250 = "2XL430-W250"
    XC430_W150 = "XC430-W150"
    XC430_W240 = "XC430-W240"
    TWO_XC430_W250 = "2XC430-W250"
    MX_28_2 = "MX-28(2.0)"


# The baud rates a Dynamixel X servo's Baud Rate register (8) holds that dynamixel-sdk can also set,
# in register order (values 0-6; 7 is 4.5 Mbps, which the SDK cannot set). ROBOTIS e-manual, XM430-W350.
SERVO_BAUDS: tuple[int, ...] = (9600, 57600, 115200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)


__all__ = [
    "LOADCELL_FORMAT_TRAITS",
    "SERVO_BAUDS",
    "SLIP_LIKE",
    "UART_BITS_PER_BYTE",
    "LoadCellFormatName",
    "LoadCellFormatTraits",
    "RigKind",
    "ServoModel",
    "ServoRole",
    "SlipEventKind",
    "StepKind",
    "TrialKind",
    "TrialOutcome",
]


class ConfigurationSourceKind(StrEnum):
    """Where a run's measured link configuration comes from (`configuration.source:` of a rig config)."""

    SIMULATOR = "simulator"  # the simulated world, with the preset's measurement noise
    OPERATOR = "operator"  # a person types the angles at a prompt
    FILE = "file"  # measured angles per configuration index, from a CSV or YAML file
    CAMERA = "camera"  # fiducial markers seen by a calibrated camera (optional extra)
    COMMAND = "command"  # nothing is measured: the commanded angles stand in


class MeasurementStage(StrEnum):
    """When in a trial a configuration was measured (`/rig/configuration/measured`)."""

    BENT = "bent"  # after bending (and after each correction)
    AFTER_SLIP = "after_slip"  # after the slip, to tell which joint moved
