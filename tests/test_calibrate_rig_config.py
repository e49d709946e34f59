"""`rig calibrate --rig CONFIG` takes the load-cell settings from a rig config."""

from __future__ import annotations

from pathlib import Path

from rig.cli import main
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG

RIGS = Path(__file__).resolve().parent.parent / "protocols" / "rigs"


def test_simulated_rig_config_is_refused_with_a_hint(capsys):
    assert main(["calibrate", "--rig", str(DEFAULT_RIG_CONFIG), "--reference-kg", "1"]) == 2
    err = capsys.readouterr().err
    assert "hardware rig" in err and "--sim" in err and err.count("\n") == 1


def test_hardware_config_supplies_port_and_output(tmp_path, capsys):
    config = tmp_path / "lab.yaml"
    text = (RIGS / "hardware.example.yaml").read_text()
    config.write_text(text.replace("/dev/ttyACM0", str(tmp_path / "no-such-port")))
    code = main(["calibrate", "--rig", str(config), "--reference-kg", "1", "--yes", "--settle-s", "0"])
    err = capsys.readouterr().err
    assert code != 0
    # It tried the config's port (which does not exist), and wrote no calibration file.
    assert "no-such-port" in err and "Traceback" not in err and "cannot open the port" in err
    assert not (tmp_path / "loadcell-cal.json").exists()
