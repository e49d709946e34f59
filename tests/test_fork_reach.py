"""Forks on some components only: a configuration that bends a joint no fork reaches is warned about.

The warning (docs/bending.md, "Joints no fork reaches") is on `/rig/log` and the progress display
before the bend moves anything, and in the dry run; the joints are left as they are, never bent by
the (simulated) hand.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from rig.log.format import schemas
from tests.helpers import quick_then_link_validation

RIG = """\
extends: simulated
name: forks-2of8
servos:
  ids:
    - {id: 1, role: winch, model: XM430-W350}
    - {id: 2, role: bender, model: XM430-W350, component: 1}
    - {id: 3, role: bender, model: XM430-W350, component: 2}
"""

# Trial 3 bends joints 1, 3 and 4 (the fork on component 1 moves); trial 4 only joints 3 and 4
# (no fork has anything to do).
PROTOCOL = quick_then_link_validation(
    "beyond-the-forks",
    configurations_deg=[[5, 0, 5, 5, 0, 0, 0, 0], [0, 0, 5, 5, 0, 0, 0, 0], [5, 5, 0, 0, 0, 0, 0, 0]],
)

WARNING_START = "configuration {index} bends joints 3, 4, which no fork of"


def _files(write_file: Callable[[str, str], Path]) -> tuple[Path, Path]:
    return write_file(PROTOCOL, "lv.yaml"), write_file(RIG, "forks-2of8.yaml")


def test_the_run_warns_before_the_bend_and_leaves_the_unreached_joints_as_they_are(
    write_file: Callable[[str, str], Path], run_cli: Callable[..., Any], tmp_path: Path
) -> None:
    protocol, rig = _files(write_file)
    done = run_cli("run", protocol, "--rig", rig, "--devices", "object", "--out", tmp_path / "out")
    assert done.code == 0, done.err
    for index in (1, 2):  # on the progress display
        assert WARNING_START.format(index=index) in done.err
    assert "configuration 3 bends" not in done.err  # the forks reach joints 1 and 2
    logged: list[tuple[int, str]] = []  # (log time, WARNING text)
    measured: dict[int, list[float]] = {}  # trial -> its last measured configuration
    bender_goals_ns: list[int] = []  # when a bender was sent a goal (the first is trial 3's fork)
    with next((tmp_path / "out").glob("*.mcap")).open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
            data = json.loads(message.data)
            if channel.topic == schemas.LOG and data["level"] == 3:  # foxglove.Log WARNING
                logged.append((message.log_time, data["message"]))
            elif channel.topic == schemas.CONFIGURATION_MEASURED and data["stage"] == "bent":
                measured[data["trial_id"]] = data["joint_angles_rad"]
            elif channel.topic == schemas.SERVO_COMMAND and (data["command"], data["role"]) == (
                "goal_position",
                "bender",
            ):
                bender_goals_ns.append(message.log_time)
    warnings = [(t, text) for t, text in logged if "no fork of" in text]
    assert [text.split(":")[0] for _, text in warnings] == ["trial 3", "trial 4"]
    assert "left as they are" in warnings[0][1] and "components 1, 2" in warnings[0][1]
    # Trial 3's warning came before its fork moved.
    assert bender_goals_ns and warnings[0][0] <= min(bender_goals_ns)
    # Joints 3 and 4 stay straight (the simulated camera's noise is 0.4°), in trial 4 too: no hand bent them.
    for trial in (3, 4):
        assert max(abs(math.degrees(a)) for a in measured[trial][2:4]) < 2.0, measured[trial]
    assert abs(math.degrees(measured[3][0]) - 5.0) < 2.0  # the fork on component 1 did bend joint 1


def test_the_dry_run_names_each_configuration_once(
    write_file: Callable[[str, str], Path], run_cli: Callable[..., Any]
) -> None:
    protocol, rig = _files(write_file)
    text = run_cli("run", protocol, "--rig", rig, "--dry-run")
    assert text.code == 0
    lines = [line for line in text.out.splitlines() if line.startswith("warning: ")]
    assert [line.split(" bends")[0] for line in lines] == [f"warning: configuration {i}" for i in (1, 2)]
    data = run_cli("run", protocol, "--rig", rig, "--dry-run", "--json").data
    assert len(data["warnings"]) == 2 and data["warnings"][0].startswith(WARNING_START.format(index=1))
    # A rig with a fork on every component (or none) gives no warning.
    plain = run_cli("run", protocol, "--dry-run", "--json").data
    assert "warnings" not in plain
