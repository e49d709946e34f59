"""The servos' facts as data: model number, current sensing, stall point, no-load speed, voltage range.

One `MotorRating` per `ServoModel`, from the model's ROBOTIS e-manual page (the `source` of each
row; https://emanual.robotis.com/docs/en/dxl/x/ and .../dxl/mx/), at the voltage the page gives
the stall point for (12 V for every model here, as the rig's servo supply). They sit below the rig
config in the import layers so that validating a config can compute the winch's stall tension and
check that the winch has current-based position control; `rig.hw.dxl.control_table` takes its
models' numbers and motor constants from here.

Which models: the X-series and MX-series (Protocol 2.0 firmware) models whose control table the
rig's X430 layout covers with the 2.69 mA current unit. Left out, on purpose: the XH430-V and
XH540-V models (24 V: their voltage-limit registers are not in these tables) and the MX-64(2.0)
and MX-106(2.0) (current unit 3.36 mA, which the driver does not convert), the X330 models (another
indirect-address layout, 1 mA units), the XD and XW430 models (voltage ranges unconfirmed), and
every Protocol 1.0-only model (AX, RX, EX, DX, MX on firmware below v39), which `rig scan` names.

Torque from current: ROBOTIS takes the output torque as roughly proportional to the current, so
torque ≈ stall torque × current / stall current (the e-manual's performance graphs; ROBOTIS
support forum, "Calculation of torque value of XM430-W350-T"). The torque constant below is that
slope; not verified on hardware, where a winch is better calibrated against the load cell.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from rig.vocabulary import ServoModel

_RPM = 2.0 * math.pi / 60.0
_EMANUAL = "https://emanual.robotis.com/docs/en/dxl/"


@dataclass(frozen=True)
class MotorRating:
    """A model's facts from its e-manual page: stall point and no-load speed at 12 V (output shaft)."""

    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rad_s: float
    model_number: int = 0  # Model Number (address 0) under Protocol 2.0 firmware
    current_sensing: bool = True  # Present Current (126), Current Limit (38), Goal Current (102), mode 5
    min_voltage_v: float = 10.0  # the operating input voltage range
    max_voltage_v: float = 14.8
    source: str = ""  # the e-manual page the numbers come from

    @property
    def torque_constant_nm_per_a(self) -> float:
        """Output-shaft torque per ampere, from the stall point."""
        return self.stall_torque_nm / self.stall_current_a

    @property
    def current_based_position(self) -> bool:
        """Whether the model has Operating Mode 5 (current-based position), which the winch needs."""
        return self.current_sensing


def _rating(
    number: int, torque_nm: float, current_a: float, speed_rpm: float, page: str, *, sensing: bool = True,
    volts: tuple[float, float] = (10.0, 14.8),
) -> MotorRating:  # fmt: skip
    return MotorRating(
        stall_torque_nm=torque_nm,
        stall_current_a=current_a,
        no_load_speed_rad_s=speed_rpm * _RPM,
        model_number=number,
        current_sensing=sensing,
        min_voltage_v=volts[0],
        max_voltage_v=volts[1],
        source=_EMANUAL + page,
    )


_XL_V = (6.5, 12.0)  # XL430 / 2XL430: 6.5-12.0 V (recommended 11.1 V)
_XC_V = (6.5, 14.8)  # XC430 / 2XC430: 6.5-14.8 V (recommended 12 V)

MOTOR_RATINGS: Mapping[ServoModel, MotorRating] = MappingProxyType(
    {
        # Current sensing, 10.0-14.8 V (recommended 12 V); stall torque and current at 12 V.
        ServoModel.XM430_W350: _rating(1020, 4.1, 2.3, 46, "x/xm430-w350/"),
        ServoModel.XM430_W210: _rating(1030, 3.0, 2.3, 77, "x/xm430-w210/"),
        ServoModel.XH430_W210: _rating(1010, 2.5, 1.3, 50, "x/xh430-w210/"),
        ServoModel.XH430_W350: _rating(1000, 3.4, 1.3, 30, "x/xh430-w350/"),
        ServoModel.XM540_W150: _rating(1130, 7.3, 4.4, 53, "x/xm540-w150/"),
        ServoModel.XM540_W270: _rating(1120, 10.6, 4.4, 30, "x/xm540-w270/"),
        ServoModel.XH540_W150: _rating(1110, 7.1, 4.9, 70, "x/xh540-w150/"),
        ServoModel.XH540_W270: _rating(1100, 9.9, 4.9, 39, "x/xh540-w270/"),
        ServoModel.XW540_T140: _rating(1180, 6.9, 4.9, 72, "x/xw540-t140/"),
        # No current sensing (Present Load at 126, modes 1, 3, 4 and 16 only).
        ServoModel.XL430_W250: _rating(1060, 1.5, 1.4, 61, "x/xl430-w250/", sensing=False, volts=_XL_V),
        ServoModel.TWO_XL430_W250: _rating(
            1090, 1.5, 1.4, 61, "x/2xl430-w250/", sensing=False, volts=_XL_V
        ),
        ServoModel.XC430_W150: _rating(1070, 1.6, 1.4, 106, "x/xc430-w150/", sensing=False, volts=_XC_V),
        ServoModel.XC430_W240: _rating(1080, 1.9, 1.4, 70, "x/xc430-w240/", sensing=False, volts=_XC_V),
        ServoModel.TWO_XC430_W250: _rating(
            1160, 1.8, 1.4, 64, "x/2xc430-w250/", sensing=False, volts=_XC_V
        ),
        ServoModel.MX_28_2: _rating(30, 2.5, 1.4, 55, "mx/mx-28-2/", sensing=False),
    }
)  # fmt: skip

# Model numbers read at address 0 of a servo answering Protocol 1.0: MX on firmware below v39 (its
# Protocol 2.0 firmware reports another number, above) and models that have no Protocol 2.0 at all
# (ROBOTIS Dynamixel2Arduino `actuator.h`; e-manual pages of the AX and MX series). An X-series
# servo switched to Protocol 1.0 (Protocol Type, address 13) reports its usual number.
PROTOCOL_1_MODELS: Mapping[int, str] = MappingProxyType(
    {12: "AX-12A", 18: "AX-18A", 300: "AX-12W", 29: "MX-28", 310: "MX-64", 320: "MX-106", 360: "MX-12W"}
)
# Protocol 1.0 MX models whose Protocol 2.0 firmware the rig knows (or the e-manual names).
MX_PROTOCOL_2_NAMES: Mapping[int, str] = MappingProxyType(
    {29: "MX-28(2.0)", 310: "MX-64(2.0)", 320: "MX-106(2.0)"}
)

# The winch's hardware cap may allow at most this multiple of the rig's force ceiling.
STALL_TENSION_CEILING_RATIO = 1.25


def winch_models() -> tuple[ServoModel, ...]:
    """The models that can be the winch: those with current-based position control (mode 5)."""
    return tuple(m for m, r in MOTOR_RATINGS.items() if r.current_based_position)


def stall_tension_n(model: ServoModel, current_limit_a: float, spool_radius_m: float) -> float:
    """The line tension at which a winch of `model` stalls at `current_limit_a` on its drum."""
    return MOTOR_RATINGS[model].torque_constant_nm_per_a * current_limit_a / spool_radius_m


def current_for_tension_a(model: ServoModel, tension_n: float, spool_radius_m: float) -> float:
    """The current limit at which a winch of `model` stalls at `tension_n` (inverse of stall_tension_n)."""
    return tension_n * spool_radius_m / MOTOR_RATINGS[model].torque_constant_nm_per_a


# The input voltage each model is specified for (lowest, highest), from the ROBOTIS e-manual model
# pages (XM430-W350: 10.0-14.8 V, recommended 12.0 V; XL430-W250: 6.5-12.0 V, recommended 11.1 V).
# `rig check` compares Present Input Voltage (144) with it.
INPUT_VOLTAGE_RANGE_V: Mapping[ServoModel, tuple[float, float]] = MappingProxyType(
    {
        ServoModel.XM430_W350: (10.0, 14.8),
        ServoModel.XL430_W250: (6.5, 12.0),
    }
)

# Bus Watchdog (98) exists from this firmware version on (ROBOTIS e-manual, Bus Watchdog section of the
# X-series control tables: "available from firmware v38").
BUS_WATCHDOG_MIN_FIRMWARE = 38
