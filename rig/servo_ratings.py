"""The servos' motor ratings as data: stall torque, stall current, no-load speed, per model.

Datasheet values at 12 V from the ROBOTIS e-manual model pages (XM430-W350, XL430-W250). They sit
below the rig config in the import layers so that validating a config can compute the winch's stall
tension; `rig.hw.dxl.control_table` takes its models' motor constants from here.

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


@dataclass(frozen=True)
class MotorRating:
    """A model's stall point and no-load speed at 12 V (output shaft)."""

    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rad_s: float

    @property
    def torque_constant_nm_per_a(self) -> float:
        """Output-shaft torque per ampere, from the stall point."""
        return self.stall_torque_nm / self.stall_current_a


MOTOR_RATINGS: Mapping[ServoModel, MotorRating] = MappingProxyType(
    {
        ServoModel.XM430_W350: MotorRating(4.1, 2.3, 46.0 * 2.0 * math.pi / 60.0),
        ServoModel.XL430_W250: MotorRating(1.5, 1.4, 61.0 * 2.0 * math.pi / 60.0),
    }
)

# The winch's hardware cap may allow at most this multiple of the rig's force ceiling.
STALL_TENSION_CEILING_RATIO = 1.25


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
