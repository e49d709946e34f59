"""Control tables as data: lookups, model differences, and a cross-check against the SDK's .model files."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import dynamixel_easy_sdk
import pytest

from rig.hw.dxl.control_table import (
    BAUD_RATES,
    MODELS,
    MODELS_BY_NUMBER,
    RAD_PER_PULSE,
    SDK_BAUDS,
    TABLE_SIZE,
    XL430_W250,
    XM430_W350,
    Field,
    table_for_model,
)
from rig.vocabulary import SERVO_BAUDS, ServoModel

MODEL_DIR = Path(dynamixel_easy_sdk.__file__).parent / "control_table"


def _sdk_rows(filename: str) -> dict[str, tuple[int, int]]:
    rows: dict[str, tuple[int, int]] = {}
    section = None
    for line in (MODEL_DIR / filename).read_text().splitlines():
        if line.startswith("["):
            section = line.strip()
            continue
        parts = line.split("\t")
        if section == "[control table]" and len(parts) == 3 and parts[0].isdigit():
            rows.setdefault(parts[2], (int(parts[0]), int(parts[1])))
    return rows


@pytest.mark.parametrize(
    ("table", "filename"), [(XM430_W350, "xm430_w350.model"), (XL430_W250, "xl430_w250.model")]
)
def test_addresses_match_the_sdk_model_files(table, filename):
    rows = _sdk_rows(filename)
    checked = 0
    for name, (address, size) in rows.items():
        if name in table:
            f = table[name]
            assert (f.address, f.size) == (address, size), name
            checked += 1
        elif not name.startswith("Indirect"):
            pytest.fail(f"{table.model_name}: SDK field {name!r} missing here")
    assert checked >= 50
    mapping = (MODEL_DIR / "dynamixel.model").read_text()
    assert f"{table.model_number}\t{filename}" in mapping


def test_lookup_by_name_and_address():
    f = XM430_W350["Goal Position"]
    assert (f.address, f.size, f.access, f.area, f.signed) == (116, 4, "RW", "RAM", True)
    assert XM430_W350.at(116) is f
    assert XM430_W350.owner(118) is f and XM430_W350.at(118) is None
    assert XM430_W350.owner(14) is None  # gap
    assert XM430_W350["ID"].area == "EEPROM" and XM430_W350["Torque Enable"].area == "RAM"
    assert XM430_W350["Present Position"].scale == pytest.approx(RAD_PER_PULSE)
    assert XM430_W350["Indirect Address 1"].default == 224
    assert XM430_W350["Indirect Address 29"].address == 578 and XM430_W350["Indirect Data 56"].address == 661
    assert XM430_W350.owner(TABLE_SIZE - 1) is XM430_W350["Indirect Data 56"]
    with pytest.raises(KeyError, match="XL430-W250 has no control-table field 'Goal Current'"):
        XL430_W250["Goal Current"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        f.address = 3  # type: ignore[misc]


def test_xl430_differences():
    assert "Current Limit" not in XL430_W250 and "Goal Current" not in XL430_W250
    assert "Present Load" in XL430_W250 and "Present Current" not in XL430_W250
    assert XL430_W250.operating_modes == {1, 3, 4, 16}
    assert XL430_W250["Operating Mode"].in_range(16) and not XL430_W250["Operating Mode"].in_range(5)
    assert XM430_W350["Operating Mode"].in_range(5) and not XM430_W350["Operating Mode"].in_range(2)
    assert XL430_W250["Temperature Limit"].default == 72 and XM430_W350["Temperature Limit"].default == 80
    assert MODELS_BY_NUMBER[1060] is XL430_W250 and MODELS_BY_NUMBER[1020] is XM430_W350
    assert table_for_model("XL430-W250") is XL430_W250 and table_for_model(1020) is XM430_W350
    with pytest.raises(KeyError, match="known: XM430-W350"):
        table_for_model(1190)  # an XL330-M077: another indirect layout, not covered


def test_signed_encoding_round_trips():
    f = XM430_W350["Goal Position"]
    assert f.encode(-1) == 0xFFFFFFFF and f.decode(0xFFFFFFFF) == -1
    assert f.in_range(1_048_575) and not f.in_range(1_048_576)
    assert Field("x", 0, 1, "R", "EEPROM", 0, 0, 1).decode(0xFF) == 0xFF


def test_torque_constant_documented_value():
    assert XM430_W350.torque_constant_nm_per_a == pytest.approx(4.1 / 2.3)
    assert XM430_W350.torque_constant_nm_per_a == pytest.approx(1.78, abs=0.01)


def test_tables_reject_overlaps():
    a = Field("a", 0, 2, "R", "EEPROM", 0, 0, 1)
    b = Field("b", 1, 1, "R", "EEPROM", 0, 0, 1)
    with pytest.raises(ValueError, match="overlaps"):
        dataclasses.replace(XM430_W350, fields=(a, b))


def test_every_servo_baud_is_a_register_value_the_sdk_can_set():
    # The register holds every rate a config may name, and dynamixel-sdk can open the port at it.
    assert set(SERVO_BAUDS) <= set(SDK_BAUDS)
    assert [BAUD_RATES[r] for r in range(len(SERVO_BAUDS))] == list(SERVO_BAUDS)
    assert BAUD_RATES[7] == 4_500_000 and 4_500_000 not in SDK_BAUDS


def test_every_servo_model_has_its_control_table():
    assert sorted(MODELS) == sorted(ServoModel)
    assert all(MODELS[m].model_name == m for m in ServoModel)
