"""`rig setup-servos`: one servo at a time gets its configured ID and the bus baud, against `rig sim servos`.

Two emulated factory-fresh servos (ID 1 at 57600 baud), each on its own pty: the config's port is a
symlink that the test points at one emulator, then the other, as the operator would plug one servo,
then the next, into the adapter. Afterwards each emulator is scanned at the config's baud.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from rig.cli import main
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG

pytestmark = [pytest.mark.pty, pytest.mark.subprocess, pytest.mark.slow]


def _config(tmp_path: Path, port: Path) -> Path:
    rig = tmp_path / "hw.yaml"
    rig.write_text(
        f"""\
kind: hardware
spool_radius_m: 0.01
servos:
  port: {port}
  baud: 1000000
  ids: [{{id: 3, role: winch, model: XM430-W350}}, {{id: 7, role: bender, model: XM430-W350}}]
loadcell: {{port: /dev/null, baud: 921600, format: rig-lc1}}
article:
  joint_radius_m: 0.01
  segment_lengths_m: [0.03, 0.03]
  load: {{point_m: [0, 0, 0.03], direction: [0, -1, 0]}}
limits: {{force_ceiling_n: 50, winch_current_limit_a: 0.35}}
"""
    )
    return rig


def _point(link: Path, target: str) -> None:
    if link.is_symlink():
        link.unlink()
    os.symlink(os.path.realpath(target), link)


def _scan(capsys: pytest.CaptureFixture[str], port: str, baud: int) -> list[dict]:
    """`rig scan` at one baud (Protocol 2.0), in-process: a new interpreter would cost a second."""
    capsys.readouterr()  # only the scan's output
    assert main(["scan", "--port", port, "--baud", str(baud), "--protocol1-max-id", "-1", "--json"]) == 0
    servos: list[dict] = json.loads(capsys.readouterr().out)["servos"]
    return servos


def test_each_servo_gets_its_id_and_the_bus_baud(tmp_path, dxl_server, monkeypatch, capsys):
    first = dxl_server(ids=[1], baud=57_600)
    second = dxl_server(ids=[1], baud=57_600)
    port = tmp_path / "adapter"
    _point(port, first.link)
    prompts: list[str] = []

    def operator(prompt: str) -> str:
        prompts.append(prompt)
        _point(port, first.link if len(prompts) == 1 else second.link)  # plug in the next servo
        return ""

    monkeypatch.setattr("sys.stdin.isatty", lambda: True)
    monkeypatch.setattr("builtins.input", operator)
    assert main(["setup-servos", "--rig", str(_config(tmp_path, port))]) == 0
    out = capsys.readouterr().out
    assert len(prompts) == 2 and "winch servo (XM430-W350, to become id 3)" in prompts[0]
    assert "id 1 -> 3, baud 57600 -> 1000000 (read back)" in out
    assert "id 1 -> 7, baud 57600 -> 1000000 (read back)" in out
    assert [(s["id"], s["baud"]) for s in _scan(capsys, first.link, 1_000_000)] == [(3, 1_000_000)]
    assert [(s["id"], s["baud"]) for s in _scan(capsys, second.link, 1_000_000)] == [(7, 1_000_000)]
    assert _scan(capsys, first.link, 57_600) == []  # nothing left at the old rate


def test_two_servos_connected_at_once_are_refused_until_one_is_left(
    tmp_path, dxl_server, monkeypatch, capsys
):
    both = dxl_server(ids=[1, 2], baud=57_600)
    answers = iter(["", "q"])
    monkeypatch.setattr("sys.stdin.isatty", lambda: True)
    monkeypatch.setattr("builtins.input", lambda prompt: next(answers))
    assert main(["setup-servos", "--rig", str(_config(tmp_path, Path(both.link)))]) == 1
    out = capsys.readouterr().out
    assert "2 servos answered (id 1 (XM430-W350) at 57600 baud, id 2 (XM430-W350) at 57600 baud)" in out
    assert "connect only one" in out and "stopped by the operator" in out
    assert [s["id"] for s in _scan(capsys, both.link, 57_600)] == [1, 2]  # nothing was written


def test_without_a_terminal_it_exits_2_saying_why(tmp_path, dxl_server):
    server = dxl_server(ids=[1], baud=57_600)
    run = subprocess.run(
        [sys.executable, "-m", "rig.cli", "setup-servos", "--rig", str(_config(tmp_path, Path(server.link)))],
        stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert run.returncode == 2
    assert "needs a terminal on stdin" in run.stderr and "ssh -t" in run.stderr
    assert "Traceback" not in run.stderr


def test_a_simulated_rig_has_no_servos_to_set_up(capsys):
    assert main(["setup-servos", "--rig", str(DEFAULT_RIG_CONFIG)]) == 2
    assert "servos.port: sim://dxl is not a serial port" in capsys.readouterr().err
