"""`rig scan` and `rig ports`: the real CLI against `rig sim servos` on a pty (real time, a few seconds)."""

from __future__ import annotations

import json

import pytest

from rig.cli import main


@pytest.mark.slow
@pytest.mark.pty
@pytest.mark.subprocess
def test_scan_finds_emulated_servos_at_their_baud_only(dxl_server, capsys):
    server = dxl_server(ids=[3, 1], baud=57_600)
    # The default rates, 57600 and 1000000. The Protocol 1.0 search at both covers the servos' IDs
    # (each of IDs 4-31, the rest of the default search, is 35 ms of silence per rate).
    assert main(["scan", "--port", server.link, "--protocol1-max-id", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out == {
        "port": server.link,
        "servos": [
            {
                "id": 1,
                "model_number": 1020,
                "model": "XM430-W350",
                "firmware": 48,
                "baud": 57_600,
                "protocol": 2.0,
            },
            {
                "id": 3,
                "model_number": 1020,
                "model": "XM430-W350",
                "firmware": 48,
                "baud": 57_600,
                "protocol": 2.0,
            },
        ],
    }


@pytest.mark.slow
@pytest.mark.pty
@pytest.mark.subprocess
def test_scan_at_1m_prints_a_table(dxl_server, capsys):
    server = dxl_server(ids=[5], baud=1_000_000, model="XL430-W250", extra_args=["--firmware", "44"])
    assert main(["scan", "--port", server.link, "--baud", "1000000", "--protocol1-max-id", "5"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].split() == ["id", "model", "model", "number", "firmware", "baud", "protocol"]
    assert lines[2].split() == ["5", "XL430-W250", "1060", "44", "1000000", "2.0"]
    assert "1 servo(s) at 1000000 baud" in lines[-1]


@pytest.mark.slow
@pytest.mark.pty
@pytest.mark.subprocess
def test_scan_with_nothing_answering_says_where_else_to_look(dxl_server, capsys):
    server = dxl_server(ids=[1], baud=57_600)
    # JSON: an empty list (the Protocol 1.0 search at IDs 0-2 covers the servo's ID).
    args = ["scan", "--port", server.link, "--baud", "1000000", "--protocol1-max-id", "2"]
    assert main([*args, "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"port": server.link, "servos": []}
    # Text: where else to look.
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "no servos answered at 1000000 baud" in out
    assert "servo supply on?" in out
    assert "--baud 57600" in out and "--baud 1000000" not in out  # the rates not scanned
    assert "searched at IDs 0-2: --protocol1-max-id 252" in out
    # Following the hint finds the servo.
    assert main(["scan", "--port", server.link, "--baud", "57600", "--protocol1-max-id", "-1"]) == 0
    assert "1 servo(s) at 57600 baud" in capsys.readouterr().out


@pytest.mark.slow
@pytest.mark.pty
@pytest.mark.subprocess
def test_scan_names_a_protocol_1_servo_and_how_to_switch_it(dxl_server, capsys):
    # An XM430-W350 switched to Protocol 1.0 (Protocol Type 1): a 2.0 ping does not find it.
    server = dxl_server(ids=[4], baud=57_600, extra_args=["--protocol", "1.0"])
    args = ["scan", "--port", server.link, "--baud", "57600", "--protocol1-max-id", "6"]
    assert main([*args, "--json"]) == 0
    (found,) = json.loads(capsys.readouterr().out)["servos"]
    assert found["id"] == 4 and found["protocol"] == 1.0 and found["baud"] == 57_600
    assert found["model"] == "XM430-W350" and found["model_number"] == 1020 and found["firmware"] == 48
    assert "write 2 to its Protocol Type (address 13)" in found["switch"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "servo 4 (XM430-W350) answers Protocol 1.0" in out and "DYNAMIXEL Wizard 2.0" in out
    # Without the Protocol 1.0 search it is not found at all (what `rig scan` did before).
    assert main([*args[:-2], "--protocol1-max-id", "-1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["servos"] == []


def test_protocol_1_advice_per_kind_of_servo():
    from rig.hw.dxl.discovery import protocol1_advice, protocol1_model_name

    assert protocol1_model_name(29) == "MX-28" and "MX-28(2.0)" in protocol1_advice(29)
    assert "Firmware Recovery" in protocol1_advice(29) and "does not support" not in protocol1_advice(29)
    assert "does not support the MX-64(2.0)" in protocol1_advice(310)
    assert protocol1_model_name(12) == "AX-12A" and "cannot drive it" in protocol1_advice(12)
    assert "Protocol Type (address 13)" in protocol1_advice(1030)


def test_scan_of_a_missing_port_exits_2_naming_it(tmp_path, capsys):
    missing = tmp_path / "ttyUSB9"
    assert main(["scan", "--port", str(missing)]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "no such serial port" in err
    assert "Traceback" not in err


def test_scan_rejects_a_baud_the_sdk_cannot_set(tmp_path, capsys):
    assert main(["scan", "--port", str(tmp_path), "--baud", "4500000"]) == 2
    assert "--baud 4500000" in capsys.readouterr().err


@pytest.mark.parametrize("as_json", [True, False], ids=["json", "text"])
def test_ports_lists_serial_ports(capsys, as_json):
    from serial.tools import list_ports

    expected = sorted(p.device for p in list_ports.comports())
    assert main(["ports", *(["--json"] if as_json else [])]) == 0
    out = capsys.readouterr().out
    if as_json:
        ports = json.loads(out)["ports"]
        assert [p["device"] for p in ports] == expected
        assert all(set(p) == {"device", "description", "hwid", "vid", "pid", "serial_number", "manufacturer"}
                   for p in ports)  # fmt: skip
    else:
        for device in expected:
            assert device in out
        if not expected:
            assert "no serial ports found" in out
