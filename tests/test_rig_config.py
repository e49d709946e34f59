"""Rig config validation: every bad field is named with what is allowed; the shipped configs load."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.errors import ConfigError, InputError
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, load_rig_config
from rig.sim.settings import load_checked_rig_config

RIGS = Path(__file__).resolve().parent.parent / "protocols" / "rigs"


def test_shipped_configs_load():
    sim = load_rig_config()
    assert sim.source == DEFAULT_RIG_CONFIG and sim.text == DEFAULT_RIG_CONFIG.read_text(encoding="utf-8")
    assert sim.kind == "simulated" and sim.servos.winch.servo_id == 1 and sim.article.joint_count == 8
    hw = load_rig_config(RIGS / "hardware.example.yaml")
    assert hw.kind == "hardware" and hw.servos.watchdog_ms == 500
    assert hw.loadcell.calibration_path == RIGS / "loadcell-cal.json"


@pytest.mark.parametrize(
    ("old", "new", "needle"),
    [
        ("baud: 1000000", "baud: 12345", "servos.baud"),
        ("role: winch", "role: wench", "servos.ids[0].role"),
        ("{id: 2, role: bender", "{id: 1, role: bender", "duplicate servo id"),
        ("kind: simulated", "kind: simulted", "kind"),
        ("spool_radius_m: 0.01", "spool_radius_m: -0.01", "spool_radius_m"),
        ("format: rig-lc1", "format: nmea", "loadcell.format"),
        ("direction: [0, -1, 0]", "direction: [0, 0, 0]", "load.direction"),
        ("max_winch_travel_rev: 20", "max_winch_travl_rev: 20", "max_winch_travl_rev"),
        ("preset: link1", "preset: link9", "simulation.preset"),
    ],
)
def test_bad_field_is_named(tmp_path, old, new, needle):
    text = DEFAULT_RIG_CONFIG.read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / "rig.yaml"
    path.write_text(text.replace(old, new))
    with pytest.raises(ConfigError) as exc:
        load_checked_rig_config(path)
    message = str(exc.value)
    assert str(path) in message and needle in message and "\n" not in message


def test_malformed_yaml_names_the_line(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text("kind: [simulated\n")
    with pytest.raises(InputError, match=r"rig.yaml: malformed YAML at line"):
        load_rig_config(path)


@pytest.mark.parametrize("name", ["a" * 256, "cal/" + "b" * 300 + ".json"])
def test_a_file_name_too_long_for_the_file_system_is_named(tmp_path, name):
    # Found by the input fuzzer: a dry run's "calibration not made yet" check stat()ed such a
    # name and raised OSError(ENAMETOOLONG) instead of a config error.
    text = (RIGS / "hardware.example.yaml").read_text(encoding="utf-8")
    path = tmp_path / "rig.yaml"
    path.write_text(text.replace("calibration: loadcell-cal.json", f"calibration: {name}"))
    with pytest.raises(
        ConfigError, match=r"loadcell\.calibration: a path component of \d+ bytes; allowed: at most 255"
    ):
        load_rig_config(path)


def test_a_hardware_config_may_describe_its_twin_and_its_own_commands_ignore_it(tmp_path):
    # `rig sim rig` serves a hardware config's `simulation:` section behind its ports (issue 30);
    # the rig's run and checks go on as without it: no simulated cell rate, no simulated rig.
    from rig.inputs.rig_config import DEFAULT_LOADCELL_RATE_HZ, nominal_loadcell_rate_hz
    from rig.sim.settings import require_simulated, simulation_section

    text = (RIGS / "hardware.example.yaml").read_text(encoding="utf-8")
    assert "  rate_hz: 10 " in text
    text = text.replace("  rate_hz: 10 ", "  # rate_hz: 10 ")
    path = tmp_path / "hw.yaml"
    path.write_text(text + "simulation:\n  winch_reversed: true\n  loadcell_rate_hz: 500\n")
    config = load_rig_config(path)
    assert config.kind == "hardware" and simulation_section(config).winch_reversed
    assert config.loadcell.rate_hz is None and nominal_loadcell_rate_hz(config) == DEFAULT_LOADCELL_RATE_HZ
    with pytest.raises(ConfigError, match="needs kind: simulated"):
        require_simulated(config)
    path.write_text(text + "simulation:\n  preset: link9\n")
    with pytest.raises(ConfigError, match=r"hw.yaml: simulation.preset"):
        load_checked_rig_config(path)
    path.write_text(text)
    with pytest.raises(ConfigError, match="simulation: missing"):
        simulation_section(load_rig_config(path))
