"""A bad `simulation:` section stops every command that loads the rig config: exit 2, one line.

The section is the simulator's (issue 30): `rig.inputs.rig_config` keeps it as written and
`rig.sim.settings` parses it, so each command that loads a config for a rig has to have it checked.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rig.errors import ConfigError
from rig.inputs.rig_config import parse_rig_config
from rig.sim.settings import check_simulation
from tests.helpers import QUICK_PROTOCOL

RIGS = Path(__file__).resolve().parent.parent / "protocols" / "rigs"
BAD_SECTION = "simulation:\n  preset: link9\n"  # the field the message must name: simulation.preset


def _simulated(tmp_path: Path) -> Path:
    rig = tmp_path / "sim-rig.yaml"
    rig.write_text(f"extends: simulated\n{BAD_SECTION}", encoding="utf-8")
    return rig


def _hardware(tmp_path: Path) -> Path:
    """The lab's template with a bad twin section (the section `rig sim rig` serves)."""
    text = (RIGS / "hardware.example.yaml").read_text(encoding="utf-8")
    rig = tmp_path / "hw-rig.yaml"
    rig.write_text(text + BAD_SECTION, encoding="utf-8")
    return rig


def _protocol(tmp_path: Path) -> Path:
    protocol = tmp_path / "quick.yaml"
    protocol.write_text(QUICK_PROTOCOL, encoding="utf-8")
    return protocol


# Each command's arguments past the rig config; PROTOCOL and OUT stand for files in tmp_path.
COMMANDS = {
    "run": (_simulated, ["run", "PROTOCOL", "--out", "OUT"]),
    "run --dry-run": (_simulated, ["run", "PROTOCOL", "--dry-run"]),
    "study": (_simulated, ["study", "PROTOCOL", "--seeds", "0", "--jobs", "1"]),
    "check": (_simulated, ["check"]),
    "sim rig": (_hardware, ["sim", "rig"]),
    "calibrate": (_hardware, ["calibrate", "--reference-kg", "1", "--yes"]),
    "setup-servos": (_hardware, ["setup-servos"]),
}


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_refuses_a_bad_simulation_section(tmp_path: Path, run_cli, command: str) -> None:
    make_rig, argv = COMMANDS[command]
    rig = make_rig(tmp_path)
    out = tmp_path / "out"
    names = {"PROTOCOL": _protocol(tmp_path), "OUT": out}
    result = run_cli(*[names.get(a, a) for a in argv], "--rig", rig)
    assert result.code == 2, result.err
    (line,) = result.err.strip().splitlines()
    assert str(rig) in line and "simulation.preset" in line and "link1" in line
    assert not out.exists()


def test_the_rig_config_keeps_the_section_as_written_and_the_simulator_parses_it() -> None:
    data = yaml.safe_load("extends: simulated\n" + BAD_SECTION)
    config = parse_rig_config(data, source="r.yaml")
    assert config.simulation is not None and config.simulation.data["preset"] == "link9"
    with pytest.raises(ConfigError, match=r"^r\.yaml: simulation\.preset: .*link1"):
        check_simulation(config)
