"""`rig sim servos` argument checking and `--fault` spec parsing (the serving path is in test_dxl_pty.py)."""

from __future__ import annotations

import argparse

import pytest

from rig.cli import sim_servos
from rig.errors import InputError
from rig.sim.dxl.faults import FaultSpec, parse_fault


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--ids", "1,300"], "--ids 1,300: 300 out of range; allowed: 0..252"),
        (["--ids", "1,x"], "'x' is not an integer"),
        (["--ids", "2,2"], "appears twice"),
        (["--baud", "12345"], "--baud 12345: not a Dynamixel baud rate; allowed: 9600"),
        (["--model", "AX-12"], "--model AX-12: unknown model; allowed: XM430-W350, XL430-W250"),
        (["--fault", "drop:0"], "count 0 out of range; allowed: 1..1000000"),
        (["--fault", "silent:9"], "no servo 9"),
        (["--fault", "baud:1:1234"], "not a Dynamixel baud rate"),
        (["--fault", "explode"], "not a fault spec; allowed: drop:N[:ID]"),
    ],
)
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, argv, message):
    link = tmp_path / "dxl"
    assert sim_servos.main([*argv, "--link", str(link)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not link.exists()  # nothing started


def test_fault_specs_parse():
    assert parse_fault("drop:3") == FaultSpec("drop", count=3)
    assert parse_fault("corrupt:2:7") == FaultSpec("corrupt", count=2, servo_id=7)
    assert parse_fault("delay:1:40:2") == FaultSpec("delay", count=1, delay_ms=40.0, servo_id=2)
    assert parse_fault("hwerror:1:0x20") == FaultSpec("hwerror", servo_id=1, bits=0x20)
    assert parse_fault("baud:4:57600") == FaultSpec("baud", servo_id=4, baud=57600)
    with pytest.raises(InputError, match="bits 0 out of range"):
        parse_fault("hwerror:1:0")


def test_build_bus_applies_faults():
    parser = __import__("argparse").ArgumentParser()
    sim_servos.add_arguments(parser)
    args = parser.parse_args(
        [
            "--ids",
            "1,2",
            "--link",
            "x",
            "--fault",
            "hwerror:2:0x04",
            "--fault",
            "baud:1:57600",
            "--fault",
            "drop:2",
        ]
    )
    bus, specs = sim_servos.build_bus(args)
    assert len(specs) == 3
    assert bus[2].hardware_error == 0x04 and bus[1].baud == 57600 and bus.faults.active


def test_a_bus_of_mixed_models_serves_each_id_its_own():
    # Two XM430-W350 and an XM430-W210 on one bus, as a lab's winch, bender and fork may be.
    parser = argparse.ArgumentParser()
    sim_servos.add_arguments(parser)
    args = parser.parse_args(["--ids", "1,2,3", "--model", "XM430-W350,XM430-W350,XM430-W210", "--link", "x"])
    bus, _ = sim_servos.build_bus(args)
    assert [bus.servo(i).table.model_name for i in (1, 2, 3)] == ["XM430-W350", "XM430-W350", "XM430-W210"]
    one = parser.parse_args(["--ids", "1,2", "--model", "XL430-W250", "--link", "x"])
    assert {s.table.model_name for s in sim_servos.build_bus(one)[0].servos} == {"XL430-W250"}
    for bad, message in (
        ("XM430-W350,XM430-W210", "2 models for 3 --ids; allowed: one model, or one per ID"),
        ("XM430-W350,AX-12,XM430-W210", "unknown model 'AX-12'; allowed: XM430-W350"),
    ):
        with pytest.raises(InputError, match=message):
            sim_servos.build_bus(parser.parse_args(["--ids", "1,2,3", "--model", bad, "--link", "x"]))
