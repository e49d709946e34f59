"""Unit tests of the servo layer's pure parts: SI conversions, signed decoding, error decoding, validation."""

import math

import pytest
from dynamixel_sdk import COMM_RX_TIMEOUT
from hypothesis import given
from hypothesis import strategies as st

from rig.errors import HardwareFault, InputError
from rig.hw.clock import SystemClock
from rig.hw.dxl import control_table as ct
from rig.hw.dxl import units as units
from rig.hw.dxl.bus import DynamixelServoBus
from rig.hw.dxl.control_table import model_name_for, model_number_for
from rig.hw.dxl.error_codes import (
    comm_result_name,
    describe_hardware_error,
    error_number_name,
    hardware_error_words,
    hardware_fault,
)
from rig.inputs.rig_config import ServoSpec


@pytest.mark.parametrize(
    ("raw", "size", "expected"),
    [(0xFFFFFFFF, 4, -1), (0x80000000, 4, -(2**31)), (0x7FFFFFFF, 4, 2**31 - 1), (0xFFFF, 2, -1),
     (0x8000, 2, -32768), (0x7FFF, 2, 32767), (0xFF, 1, -1), (5, 4, 5)],
)  # fmt: skip
def test_to_signed_decodes_twos_complement(raw, size, expected):
    assert units.to_signed(raw, size) == expected


@given(st.integers(min_value=-(2**31), max_value=2**31 - 1))
def test_signed_round_trip_through_wire_bytes(value):
    data = units.to_le_bytes(value, 4)
    assert len(data) == 4 and all(0 <= b <= 255 for b in data)
    assert units.from_le_bytes(data, 0, 4, signed=True) == value


def test_to_unsigned_rejects_values_that_do_not_fit():
    with pytest.raises(ValueError, match="does not fit"):
        units.to_unsigned(70000, 2)
    with pytest.raises(ValueError, match="does not fit"):
        units.to_unsigned(-40000, 2)


def test_si_constants_match_the_control_table_scales():
    table = ct.XM430_W350
    assert table["Present Position"].scale == pytest.approx(units.RAD_PER_PULSE)
    assert table["Present Velocity"].scale == pytest.approx(units.RAD_S_PER_VELOCITY_UNIT)
    assert table["Present Current"].scale == pytest.approx(units.CURRENT_UNIT_A)
    assert table["Profile Acceleration"].scale == pytest.approx(units.RAD_S2_PER_ACCELERATION_UNIT)


def test_unit_values_from_the_manual():
    assert units.position_rad_from_pulses(4096) == pytest.approx(2 * math.pi)
    assert units.position_rad_from_pulses(-2048) == pytest.approx(-math.pi)
    # 1 unit = 0.229 rpm = 0.0239809 rad/s; 2.69 mA; 214.577 rev/min^2 = 0.374507 rad/s^2
    assert units.velocity_rad_s_from_units(1) == pytest.approx(0.229 * 2 * math.pi / 60)
    assert units.current_a_from_units(-1193) == pytest.approx(-3.20917)
    assert units.acceleration_rad_s2_from_units(1) == pytest.approx(0.374507, rel=1e-5)
    assert units.voltage_v_from_units(120) == pytest.approx(12.0)


@given(st.floats(min_value=-1600.0, max_value=1600.0, allow_nan=False))
def test_position_round_trip_within_half_a_pulse(angle_rad):
    pulses = units.pulses_from_position_rad(angle_rad)
    assert abs(units.position_rad_from_pulses(pulses) - angle_rad) <= units.RAD_PER_PULSE / 2 + 1e-12


@given(st.floats(min_value=-3.2, max_value=3.2, allow_nan=False))
def test_current_round_trip_within_half_a_unit(current_a):
    assert (
        abs(units.current_a_from_units(units.current_units_from_a(current_a)) - current_a) <= 0.001345 + 1e-12
    )


def test_hardware_error_words():
    assert hardware_error_words(0) == []
    assert hardware_error_words(0x20) == ["overload"]
    assert hardware_error_words(0x01 | 0x04 | 0x08 | 0x10 | 0x20) == [
        "input voltage", "overheating", "encoder", "electrical shock", "overload"
    ]  # fmt: skip
    assert hardware_error_words(0x42) == ["unknown bits 0x42"]
    assert describe_hardware_error(0x24) == "0x24 (overheating, overload)"
    assert describe_hardware_error(0) == "none"


def test_hardware_fault_names_servo_role_and_words():
    fault = hardware_fault(2, "winch", 0x20, "state read")
    assert isinstance(fault, HardwareFault)
    assert fault.servo_id == 2 and fault.role == "winch" and fault.hardware_error == 0x20
    assert fault.words == ["overload"]
    text = str(fault)
    assert "servo 2 (winch)" in text and "overload" in text and "reboot" in text


def test_error_number_and_comm_result_names():
    assert error_number_name(0x87) == "access error"  # the alert bit is ignored
    assert error_number_name(0x04) == "data range error"
    assert comm_result_name(COMM_RX_TIMEOUT) == "timeout (no status packet)"
    assert "unknown" in comm_result_name(-1)


def test_model_names_and_numbers():
    assert model_number_for("XM430-W350") == 1020
    assert model_number_for("XL430-W250") == 1060
    assert model_name_for(1060) == "XL430-W250"
    assert model_name_for(1234) == "unknown (1234)"
    with pytest.raises(InputError, match="XM430-W350"):
        model_number_for("MX-28")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"baud": 4_500_000}, "cannot be set"),
        ({"servos": []}, "no servos"),
        (
            {"servos": [ServoSpec(1, "winch", "XM430-W350"), ServoSpec(1, "bender", "XM430-W350")]},
            "more than once",
        ),
        ({"servos": [ServoSpec(253, "winch", "XM430-W350")]}, "0-252"),
        ({"servos": [ServoSpec(1, "winch", "AX-12")]}, "unknown"),
        ({"retries": -1}, "retries"),
        ({"bus_watchdog_ms": 5000}, "watchdog"),
    ],
    ids=["baud", "empty", "duplicate", "id-range", "model", "retries", "watchdog"],
)
def test_construction_rejects_bad_configuration(kwargs, match):
    args = {"port_name": "/dev/null", "baud": 1_000_000, "servos": [ServoSpec(1, "winch", "XM430-W350")],
            "clock": SystemClock()} | kwargs  # fmt: skip
    with pytest.raises(InputError, match=match):
        DynamixelServoBus(**args)
