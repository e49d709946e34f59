"""Dynamixel X-series (Protocol 2.0) control tables as data: the single source of truth for addresses.

One frozen `Field` per row (name, address, size, access, area, default, range, sign, unit, scale)
and one `ControlTable` per model with O(1) lookup by name and by address. The hardware driver, the
servo emulator (`rig.sim.dxl`) and the CLI all import from here, so each fact is written down once:
addresses, unit constants, the baud-rate tables (the Baud Rate register's rates and the rates
dynamixel-sdk can set), model name <-> number lookup, and two's-complement decoding (`to_signed`).

Models: every `ServoModel`, one table each built from one X430 layout (`_x430_fields`, from the
XM430-W350 and XL430-W250 e-manual pages, summarised in docs/design.md §7): the model's number and
motor constants come from `rig.inputs.servo_ratings`, where it differs from the XM430-W350 (limits,
defaults) from `_TABLE_DEFAULTS`. A model without current sensing (XL430, XC430, their 2X
versions, MX-28(2.0)) has no Current Limit (38) or Goal Current (102), reports Present Load (0.1 %
of stall torque) at 126 instead of Present Current, and supports operating modes 1, 3, 4 and 16
only. The X540 models' External Port registers (56-58, 152-157) and the MX-28(2.0)'s Acceleration
Limit (40) are not in the table: the rig does not use them.

The motor constants (`stall_torque_nm`, `stall_current_a`, `no_load_speed_rad_s`) are the
datasheet values at 12 V; `torque_constant_nm_per_a = stall_torque_nm / stall_current_a` is the
output-shaft torque per ampere the emulator uses (XM430-W350: 4.1 N·m / 2.3 A ≈ 1.78 N·m/A).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal

from rig.errors import InputError
from rig.inputs.servo_ratings import MOTOR_RATINGS
from rig.vocabulary import SERVO_BAUDS, ServoModel

# Conversion constants for raw control-table units.
PULSES_PER_REV = 4096
RAD_PER_PULSE = 2.0 * math.pi / PULSES_PER_REV
VELOCITY_UNIT_RPM = 0.229
RAD_S_PER_VELOCITY_UNIT = VELOCITY_UNIT_RPM * 2.0 * math.pi / 60.0
CURRENT_UNIT_A = 0.00269
VOLTAGE_UNIT_V = 0.1
PWM_UNIT_PERCENT = 0.113
ACCELERATION_UNIT_REV_MIN2 = 214.577
RAD_S2_PER_ACCELERATION_UNIT = ACCELERATION_UNIT_REV_MIN2 * 2.0 * math.pi / 3600.0
RETURN_DELAY_UNIT_S = 2e-6
BUS_WATCHDOG_UNIT_MS = 20
BUS_WATCHDOG_UNIT_S = BUS_WATCHDOG_UNIT_MS / 1000
BUS_WATCHDOG_TRIPPED = 0xFF  # Bus Watchdog (98) reads -1 after a trip, until 0 is written
LOAD_UNIT_PERCENT = 0.1  # XL430 Present Load

EEPROM_END = 64  # addresses below this are EEPROM (locked while Torque Enable = 1)
TABLE_SIZE = 662  # the table ends at Indirect Data 56 (661)
FAST_READ_MIN_FIRMWARE = 45
GOAL_POSITION_LIMIT_PULSES = 1_048_575  # Goal Position range in modes 4 and 5: +-256 rev

# Addresses shared by every X430/X540 table (kept as names for readability in the emulator/driver).
ADDR_MODEL_NUMBER = 0
ADDR_FIRMWARE_VERSION = 6
ADDR_ID = 7
ADDR_BAUD_RATE = 8
ADDR_RETURN_DELAY_TIME = 9
ADDR_DRIVE_MODE = 10
ADDR_OPERATING_MODE = 11
ADDR_TORQUE_ENABLE = 64
ADDR_STATUS_RETURN_LEVEL = 68
ADDR_HARDWARE_ERROR_STATUS = 70
ADDR_GOAL_CURRENT = 102
ADDR_GOAL_POSITION = 116
ADDR_PRESENT_CURRENT = 126
ADDR_PRESENT_VELOCITY = 128
ADDR_PRESENT_POSITION = 132

# Baud Rate (8) register value -> bit/s: 0-6 are the rates dynamixel-sdk can also set (SERVO_BAUDS,
# in register order), 7 is 4.5 Mbps.
BAUD_RATES: Mapping[int, int] = MappingProxyType({**dict(enumerate(SERVO_BAUDS)), 7: 4_500_000})
BAUD_REGISTER_BY_RATE: Mapping[int, int] = MappingProxyType({v: k for k, v in BAUD_RATES.items()})
# Baud rates dynamixel-sdk's PortHandler.setBaudRate accepts (it has no 4.5 Mbps).
SDK_BAUDS = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1_000_000,
             1_152_000, 2_000_000, 2_500_000, 3_000_000, 3_500_000, 4_000_000)  # fmt: skip

# Hardware Error Status (70) / Shutdown (63) bits.
HW_ERROR_INPUT_VOLTAGE = 0x01
HW_ERROR_OVERHEATING = 0x04
HW_ERROR_ENCODER = 0x08
HW_ERROR_ELECTRICAL_SHOCK = 0x10
HW_ERROR_OVERLOAD = 0x20

INDIRECT_ADDRESS_BLOCKS = ((168, 224, 28, 1), (578, 634, 28, 29))  # (address base, data base, count, first n)

Access = Literal["R", "RW"]
Area = Literal["EEPROM", "RAM"]


def to_signed(raw: int, size_bytes: int) -> int:
    """Interpret an unsigned `size_bytes`-wide value as two's complement."""
    bits = 8 * size_bytes
    raw &= (1 << bits) - 1
    return raw - (1 << bits) if raw >= 1 << (bits - 1) else raw


@dataclass(frozen=True, slots=True)
class Field:
    """One control-table item. `min`/`max` is the static range (Data Range error outside it)."""

    name: str
    address: int
    size: int
    access: Access
    area: Area
    default: int
    min: int
    max: int
    signed: bool = False
    unit: str = ""
    scale: float = 1.0  # SI (or `unit`) per raw count
    allowed: frozenset[int] | None = None  # when set, only these values are valid (e.g. Operating Mode)

    @property
    def end(self) -> int:
        """First address after this field."""
        return self.address + self.size

    @property
    def writable(self) -> bool:
        """True for read-write fields."""
        return self.access == "RW"

    def in_range(self, value: int) -> bool:
        """Whether `value` (signed when the field is) is within the static range."""
        if self.allowed is not None:
            return value in self.allowed
        return self.min <= value <= self.max

    def decode(self, raw: int) -> int:
        """Unsigned wire value -> the field's integer value (two's complement when signed)."""
        return to_signed(raw, self.size) if self.signed else raw

    def encode(self, value: int) -> int:
        """The field's integer value -> the unsigned wire value."""
        return value & ((1 << (8 * self.size)) - 1)


@dataclass(frozen=True)
class ControlTable:
    """The control table of one model, with O(1) lookup by name and by address."""

    model_name: ServoModel
    model_number: int
    fields: tuple[Field, ...]
    operating_modes: frozenset[int]
    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rad_s: float
    default_firmware: int = 48
    size: int = TABLE_SIZE
    _by_name: Mapping[str, Field] = field(init=False, repr=False, compare=False)
    _by_address: Mapping[int, Field] = field(init=False, repr=False, compare=False)
    _owner: tuple[Field | None, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        by_name: dict[str, Field] = {}
        by_address: dict[int, Field] = {}
        owner: list[Field | None] = [None] * self.size
        for f in self.fields:
            if f.name in by_name:
                raise ValueError(f"{self.model_name}: duplicate field name {f.name!r}")
            if f.end > self.size:
                raise ValueError(
                    f"{self.model_name}: {f.name} ends at {f.end}, beyond the table ({self.size})"
                )
            for a in range(f.address, f.end):
                if owner[a] is not None:
                    raise ValueError(f"{self.model_name}: {f.name} overlaps {owner[a].name} at {a}")  # type: ignore[union-attr]
                owner[a] = f
            by_name[f.name] = f
            by_address[f.address] = f
        object.__setattr__(self, "_by_name", MappingProxyType(by_name))
        object.__setattr__(self, "_by_address", MappingProxyType(by_address))
        object.__setattr__(self, "_owner", tuple(owner))

    @property
    def torque_constant_nm_per_a(self) -> float:
        """Output-shaft torque per ampere, from the datasheet stall point."""
        return self.stall_torque_nm / self.stall_current_a

    def __getitem__(self, name: str) -> Field:
        """The field called `name` (KeyError naming the model if absent)."""
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"{self.model_name} has no control-table field {name!r}") from None

    def __contains__(self, name: object) -> bool:
        """Whether a field called `name` exists on this model."""
        return name in self._by_name

    def get(self, name: str) -> Field | None:
        """The field called `name`, or None."""
        return self._by_name.get(name)

    def at(self, address: int) -> Field | None:
        """The field that starts at `address`, or None."""
        return self._by_address.get(address)

    def owner(self, address: int) -> Field | None:
        """The field that contains byte `address` (not necessarily its first byte), or None."""
        if 0 <= address < self.size:
            return self._owner[address]
        return None

    def names(self) -> tuple[str, ...]:
        """Every field name in address order."""
        return tuple(f.name for f in self.fields)


def _f(
    address: int,
    size: int,
    name: str,
    access: Access,
    default: int,
    lo: int,
    hi: int,
    *,
    signed: bool = False,
    unit: str = "",
    scale: float = 1.0,
    allowed: Iterable[int] | None = None,
) -> Field:
    return Field(
        name=name,
        address=address,
        size=size,
        access=access,
        area="EEPROM" if address < EEPROM_END else "RAM",
        default=default,
        min=lo,
        max=hi,
        signed=signed,
        unit=unit,
        scale=scale,
        allowed=frozenset(allowed) if allowed is not None else None,
    )


_U32 = 0xFFFFFFFF
_RPM_UNIT = ("rad/s", RAD_S_PER_VELOCITY_UNIT)


def _indirect_fields() -> list[Field]:
    fields: list[Field] = []
    for addr_base, data_base, count, first in INDIRECT_ADDRESS_BLOCKS:
        for k in range(count):
            n = first + k
            fields.append(
                _f(addr_base + 2 * k, 2, f"Indirect Address {n}", "RW", data_base + k, 64, TABLE_SIZE - 1)
            )
            fields.append(_f(data_base + k, 1, f"Indirect Data {n}", "RW", 0, 0, 255))
    return fields


def _x430_fields(
    *,
    model_number: int,
    has_current: bool,
    temperature_limit: int,
    voltage_limits: tuple[int, int, int, int],  # max default, min default, range lo, range hi
    current_limit: int,
    velocity_limit: int,
    gains: tuple[int, int, int, int, int],  # velocity I, velocity P, position D, position I, position P
    modes: frozenset[int],
) -> tuple[Field, ...]:
    vmax_def, vmin_def, v_lo, v_hi = voltage_limits
    vel_unit, vel_scale = _RPM_UNIT
    rows: list[Field] = [
        _f(0, 2, "Model Number", "R", model_number, 0, 0xFFFF),
        _f(2, 4, "Model Information", "R", 0, 0, _U32),
        _f(6, 1, "Firmware Version", "R", 48, 0, 255),
        _f(7, 1, "ID", "RW", 1, 0, 252),
        _f(8, 1, "Baud Rate", "RW", 1, 0, 7),
        _f(9, 1, "Return Delay Time", "RW", 250, 0, 254, unit="s", scale=RETURN_DELAY_UNIT_S),
        _f(10, 1, "Drive Mode", "RW", 0, 0, 13),
        _f(11, 1, "Operating Mode", "RW", 3, 0, 16, allowed=modes),
        _f(12, 1, "Secondary(Shadow) ID", "RW", 255, 0, 255),
        _f(13, 1, "Protocol Type", "RW", 2, 1, 2),
        _f(
            20,
            4,
            "Homing Offset",
            "RW",
            0,
            -1_044_479,
            1_044_479,
            signed=True,
            unit="rad",
            scale=RAD_PER_PULSE,
        ),
        _f(24, 4, "Moving Threshold", "RW", 10, 0, 1023, unit=vel_unit, scale=vel_scale),
        _f(31, 1, "Temperature Limit", "RW", temperature_limit, 0, 100, unit="degC"),
        _f(32, 2, "Max Voltage Limit", "RW", vmax_def, v_lo, v_hi, unit="V", scale=VOLTAGE_UNIT_V),
        _f(34, 2, "Min Voltage Limit", "RW", vmin_def, v_lo, v_hi, unit="V", scale=VOLTAGE_UNIT_V),
        _f(36, 2, "PWM Limit", "RW", 885, 0, 885, unit="%", scale=PWM_UNIT_PERCENT),
    ]
    if has_current:
        rows.append(
            _f(38, 2, "Current Limit", "RW", current_limit, 0, current_limit, unit="A", scale=CURRENT_UNIT_A)
        )
    rows += [
        _f(44, 4, "Velocity Limit", "RW", velocity_limit, 0, 1023, unit=vel_unit, scale=vel_scale),
        _f(48, 4, "Max Position Limit", "RW", 4095, 0, 4095, unit="rad", scale=RAD_PER_PULSE),
        _f(52, 4, "Min Position Limit", "RW", 0, 0, 4095, unit="rad", scale=RAD_PER_PULSE),
        _f(63, 1, "Shutdown", "RW", 0x34, 0, 255),
        _f(64, 1, "Torque Enable", "RW", 0, 0, 1),
        _f(65, 1, "LED", "RW", 0, 0, 1),
        _f(68, 1, "Status Return Level", "RW", 2, 0, 2),
        _f(69, 1, "Registered Instruction", "R", 0, 0, 1),
        _f(70, 1, "Hardware Error Status", "R", 0, 0, 255),
        _f(76, 2, "Velocity I Gain", "RW", gains[0], 0, 16383),
        _f(78, 2, "Velocity P Gain", "RW", gains[1], 0, 16383),
        _f(80, 2, "Position D Gain", "RW", gains[2], 0, 16383),
        _f(82, 2, "Position I Gain", "RW", gains[3], 0, 16383),
        _f(84, 2, "Position P Gain", "RW", gains[4], 0, 16383),
        _f(88, 2, "Feedforward 2nd Gain", "RW", 0, 0, 16383),
        _f(90, 2, "Feedforward 1st Gain", "RW", 0, 0, 16383),
        _f(98, 1, "Bus Watchdog", "RW", 0, 0, 127, unit="s", scale=BUS_WATCHDOG_UNIT_S),
        _f(100, 2, "Goal PWM", "RW", 885, -885, 885, signed=True, unit="%", scale=PWM_UNIT_PERCENT),
    ]
    if has_current:
        rows.append(
            _f(102, 2, "Goal Current", "RW", current_limit, -current_limit, current_limit, signed=True,
               unit="A", scale=CURRENT_UNIT_A)
        )  # fmt: skip
    rows += [
        _f(104, 4, "Goal Velocity", "RW", 0, -1023, 1023, signed=True, unit=vel_unit, scale=vel_scale),
        _f(108, 4, "Profile Acceleration", "RW", 0, 0, 32767, unit="rad/s^2",
           scale=RAD_S2_PER_ACCELERATION_UNIT),
        _f(112, 4, "Profile Velocity", "RW", 0, 0, 32767, unit=vel_unit, scale=vel_scale),
        _f(116, 4, "Goal Position", "RW", 0, -GOAL_POSITION_LIMIT_PULSES, GOAL_POSITION_LIMIT_PULSES,
           signed=True, unit="rad", scale=RAD_PER_PULSE),
        _f(120, 2, "Realtime Tick", "R", 0, 0, 32767, unit="s", scale=1e-3),
        _f(122, 1, "Moving", "R", 0, 0, 1),
        _f(123, 1, "Moving Status", "R", 0, 0, 255),
        _f(124, 2, "Present PWM", "R", 0, -885, 885, signed=True, unit="%", scale=PWM_UNIT_PERCENT),
    ]  # fmt: skip
    if has_current:
        rows.append(
            _f(126, 2, "Present Current", "R", 0, -32768, 32767, signed=True, unit="A", scale=CURRENT_UNIT_A)
        )
    else:
        rows.append(
            _f(126, 2, "Present Load", "R", 0, -1000, 1000, signed=True, unit="%", scale=LOAD_UNIT_PERCENT)
        )
    rows += [
        _f(128, 4, "Present Velocity", "R", 0, -(1 << 31), (1 << 31) - 1, signed=True, unit=vel_unit,
           scale=vel_scale),
        _f(132, 4, "Present Position", "R", 0, -(1 << 31), (1 << 31) - 1, signed=True, unit="rad",
           scale=RAD_PER_PULSE),
        _f(136, 4, "Velocity Trajectory", "R", 0, -(1 << 31), (1 << 31) - 1, signed=True, unit=vel_unit,
           scale=vel_scale),
        _f(140, 4, "Position Trajectory", "R", 0, -(1 << 31), (1 << 31) - 1, signed=True, unit="rad",
           scale=RAD_PER_PULSE),
        _f(144, 2, "Present Input Voltage", "R", 120, 0, 0xFFFF, unit="V", scale=VOLTAGE_UNIT_V),
        _f(146, 1, "Present Temperature", "R", 30, 0, 255, unit="degC"),
    ]  # fmt: skip
    rows += _indirect_fields()
    rows.sort(key=lambda f: f.address)
    return tuple(rows)


@dataclass(frozen=True)
class _TableDefaults:
    """Where a model's table differs from the XM430-W350's: limits' defaults and ranges, modes.

    From the XM430-W350 and XL430-W250 e-manual pages and each model's Current Limit maximum (its
    e-manual page; ROBOTIS Dynamixel2Arduino). The gains, Temperature Limit and Voltage Limit
    defaults of the models other than those two are their family's (not checked per model): they
    are only the emulator's starting values, and the driver reads what it uses from the device.
    """

    current_limit: int = 1193  # Current Limit (38) maximum and default, 2.69 mA units; 0: no current
    temperature_limit: int = 80
    voltage_limits: tuple[int, int, int, int] = (160, 95, 95, 160)  # max default, min default, range
    velocity_limit: int | None = None  # Velocity Limit (44) default; None: the no-load speed
    gains: tuple[int, int, int, int, int] = (1920, 100, 0, 0, 800)
    has_led: bool = True  # XW: no LED (65)


_CURRENT_MODES = frozenset({0, 1, 3, 4, 5, 16})
_NO_CURRENT_MODES = frozenset({1, 3, 4, 16})
_XL430 = _TableDefaults(
    current_limit=0, temperature_limit=72, voltage_limits=(140, 60, 60, 140), velocity_limit=265,
    gains=(1000, 100, 4000, 0, 640),
)  # fmt: skip
_XC430 = _TableDefaults(current_limit=0, voltage_limits=(160, 60, 60, 160), gains=(1000, 100, 4000, 0, 640))
_X540 = _TableDefaults(current_limit=2047)
_TABLE_DEFAULTS: Mapping[ServoModel, _TableDefaults] = MappingProxyType(
    {
        ServoModel.XM430_W350: _TableDefaults(velocity_limit=200),
        ServoModel.XM430_W210: _TableDefaults(),
        ServoModel.XH430_W210: _TableDefaults(current_limit=648),
        ServoModel.XH430_W350: _TableDefaults(current_limit=648),
        ServoModel.XM540_W150: _X540,
        ServoModel.XM540_W270: _X540,
        ServoModel.XH540_W150: _X540,
        ServoModel.XH540_W270: _X540,
        ServoModel.XW540_T140: _TableDefaults(current_limit=2047, has_led=False),
        ServoModel.XL430_W250: _XL430,  # velocity limit: 265 or 415 by doc revision; read it from the device
        ServoModel.TWO_XL430_W250: _XL430,
        ServoModel.XC430_W150: _XC430,
        ServoModel.XC430_W240: _XC430,
        ServoModel.TWO_XC430_W250: _XC430,
        ServoModel.MX_28_2: _TableDefaults(current_limit=0),
    }
)


def control_table(model: ServoModel) -> ControlTable:
    """The control table of one model, from its facts (`rig.inputs.servo_ratings`) and table defaults."""
    rating = MOTOR_RATINGS[model]
    defaults = _TABLE_DEFAULTS[model]
    has_current = rating.current_sensing
    modes = _CURRENT_MODES if has_current else _NO_CURRENT_MODES
    velocity_limit = defaults.velocity_limit
    if velocity_limit is None:
        velocity_limit = min(1023, math.floor(rating.no_load_speed_rad_s / RAD_S_PER_VELOCITY_UNIT))
    fields = _x430_fields(
        model_number=rating.model_number,
        has_current=has_current,
        temperature_limit=defaults.temperature_limit,
        voltage_limits=defaults.voltage_limits,
        current_limit=defaults.current_limit,
        velocity_limit=velocity_limit,
        gains=defaults.gains,
        modes=modes,
    )
    if not defaults.has_led:
        fields = tuple(f for f in fields if f.name != "LED")
    return ControlTable(
        model_name=model,
        model_number=rating.model_number,
        fields=fields,
        operating_modes=modes,
        stall_torque_nm=rating.stall_torque_nm,
        stall_current_a=rating.stall_current_a,
        no_load_speed_rad_s=rating.no_load_speed_rad_s,
    )


MODELS: Mapping[ServoModel, ControlTable] = MappingProxyType({m: control_table(m) for m in ServoModel})
XM430_W350 = MODELS[ServoModel.XM430_W350]
XL430_W250 = MODELS[ServoModel.XL430_W250]
MODELS_BY_NUMBER: Mapping[int, ControlTable] = MappingProxyType({t.model_number: t for t in MODELS.values()})


def _table_named(name: str) -> ControlTable | None:
    """The table of a model name, or None for a name that is no `ServoModel`."""
    return MODELS[ServoModel(name)] if name in MODELS else None


def table_for_model(name_or_number: str | int) -> ControlTable:
    """The table for a model name ('XM430-W350') or number (1020); KeyError listing the known ones."""
    table = (
        MODELS_BY_NUMBER.get(name_or_number)
        if isinstance(name_or_number, int)
        else _table_named(name_or_number)
    )
    if table is None:
        known = ", ".join(f"{t.model_name} ({t.model_number})" for t in MODELS.values())
        raise KeyError(f"unknown Dynamixel model {name_or_number!r}; known: {known}")
    return table


def model_number_for(name: str) -> int:
    """Model number of a model name such as "XM430-W350"; `InputError` listing the known names."""
    table = _table_named(name)
    if table is None:
        raise InputError(f"servo model {name!r} is unknown; allowed: {', '.join(sorted(MODELS))}")
    return table.model_number


def model_name_for(number: int) -> str:
    """Model name of a model number, or "unknown (N)"."""
    table = MODELS_BY_NUMBER.get(number)
    return table.model_name if table is not None else f"unknown ({number})"
