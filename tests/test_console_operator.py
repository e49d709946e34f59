"""The console operator keeps the rig's control loop running while it waits for Enter."""

from __future__ import annotations

import os
import pty

import pytest

from rig.errors import InputError
from rig.hw.hardware_rig import ConsoleOperator
from rig.hw.session import OperatorRequest, OperatorTask


def prompt(text: str) -> OperatorRequest:
    return OperatorRequest(OperatorTask.FOLLOW_PROMPT, text, None)


def test_the_control_loop_keeps_running_until_the_operator_presses_enter(monkeypatch, capsys):
    master, slave = pty.openpty()
    with os.fdopen(slave, "r") as terminal:
        monkeypatch.setattr("sys.stdin", terminal)
        ticks: list[int] = []

        def keep_alive() -> None:
            ticks.append(1)
            if len(ticks) == 5:  # the person answers while the rig keeps being read
                os.write(master, b"\n")

        ConsoleOperator().confirm(prompt("Hook the cup at 0.10 m"), keep_alive)
    os.close(master)
    assert len(ticks) >= 5
    assert "Hook the cup at 0.10 m" in capsys.readouterr().err


def test_without_a_terminal_an_operator_step_is_an_input_error(monkeypatch):
    monkeypatch.setattr("sys.stdin", open(os.devnull))  # noqa: SIM115
    with pytest.raises(InputError, match="needs a person at a terminal"):
        ConsoleOperator().confirm(prompt("Hook the cup"), lambda: None)
