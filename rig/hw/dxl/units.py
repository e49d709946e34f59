"""Dynamixel X-series raw units <-> SI, and two's-complement decoding of control-table values.

The servo layer converts here and nowhere else: positions in rad (4096 pulses per revolution,
pulse 0 = 0 rad), velocities in rad/s (0.229 rpm per unit), currents in A (2.69 mA per unit),
profile accelerations in rad/s^2 (214.577 rev/min^2 per unit), voltages in V (0.1 V per unit),
temperatures in degC (1 degC per unit). The constants come from `rig.hw.dxl.control_table`, the one
source of truth shared with the emulator. The SDK hands every value back unsigned; `to_signed`
(defined in `control_table`, re-exported here) restores the sign of the signed fields.
"""

from __future__ import annotations

from rig.hw.dxl.control_table import (
    ACCELERATION_UNIT_REV_MIN2,
    CURRENT_UNIT_A,
    PULSES_PER_REV,
    PWM_UNIT_PERCENT,
    RAD_PER_PULSE,
    RAD_S2_PER_ACCELERATION_UNIT,
    RAD_S_PER_VELOCITY_UNIT,
    VELOCITY_UNIT_RPM,
    VOLTAGE_UNIT_V,
    to_signed,
)

__all__ = [
    "ACCELERATION_UNIT_REV_MIN2",
    "CURRENT_UNIT_A",
    "PULSES_PER_REV",
    "PWM_UNIT_PERCENT",
    "RAD_PER_PULSE",
    "RAD_S2_PER_ACCELERATION_UNIT",
    "RAD_S_PER_VELOCITY_UNIT",
    "VELOCITY_UNIT_RPM",
    "VOLTAGE_UNIT_V",
    "to_signed",
]


def to_unsigned(value: int, size_bytes: int) -> int:
    """Encode a (possibly negative) integer as the unsigned `size_bytes`-wide value the wire carries.

    Raises `ValueError` when the value does not fit the field width.
    """
    bits = 8 * size_bytes
    if not -(1 << (bits - 1)) <= value < (1 << bits):
        raise ValueError(f"{value} does not fit in {size_bytes} byte(s)")
    return value & ((1 << bits) - 1)


def to_le_bytes(value: int, size_bytes: int) -> list[int]:
    """Little-endian bytes of an unsigned or signed value, as the SDK's parameter lists want them."""
    raw = to_unsigned(value, size_bytes)
    return [(raw >> (8 * i)) & 0xFF for i in range(size_bytes)]


def from_le_bytes(data: bytes | bytearray | list[int], offset: int, size_bytes: int, signed: bool) -> int:
    """Decode `size_bytes` little-endian bytes at `offset`, two's complement when `signed`."""
    raw = 0
    for i in range(size_bytes):
        raw |= data[offset + i] << (8 * i)
    return to_signed(raw, size_bytes) if signed else raw


def position_rad_from_pulses(pulses: int) -> float:
    """Position in rad from signed pulses (multi-turn in modes 4 and 5)."""
    return pulses * RAD_PER_PULSE


def pulses_from_position_rad(position_rad: float) -> int:
    """Nearest whole pulse for a position in rad."""
    return round(position_rad / RAD_PER_PULSE)


def velocity_rad_s_from_units(units: int) -> float:
    """Velocity in rad/s from signed 0.229 rpm units."""
    return units * RAD_S_PER_VELOCITY_UNIT


def velocity_units_from_rad_s(velocity_rad_s: float) -> int:
    """Nearest 0.229 rpm unit for a velocity in rad/s."""
    return round(velocity_rad_s / RAD_S_PER_VELOCITY_UNIT)


def current_a_from_units(units: int) -> float:
    """Current in A from signed 2.69 mA units."""
    return units * CURRENT_UNIT_A


def current_units_from_a(current_a: float) -> int:
    """Nearest 2.69 mA unit for a current in A."""
    return round(current_a / CURRENT_UNIT_A)


def acceleration_units_from_rad_s2(acceleration_rad_s2: float) -> int:
    """Nearest 214.577 rev/min^2 unit for an acceleration in rad/s^2."""
    return round(acceleration_rad_s2 / RAD_S2_PER_ACCELERATION_UNIT)


def acceleration_rad_s2_from_units(units: int) -> float:
    """Acceleration in rad/s^2 from 214.577 rev/min^2 units."""
    return units * RAD_S2_PER_ACCELERATION_UNIT


def voltage_v_from_units(units: int) -> float:
    """Voltage in V from 0.1 V units."""
    return units * VOLTAGE_UNIT_V
