"""`rig sim servos` argument checking and `--fault` spec parsing (the serving path is in test_dxl_pty.py)."""

from __future__ import annotations

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
