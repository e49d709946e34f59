"""The winch's hardware tension cap means it: stall tension at most 1.25 x the force ceiling.

Validation of a rig config refuses a current limit whose stall tension (torque constant x current
limit / spool radius) exceeds 1.25 x `limits.force_ceiling_n`, in one line that names the file,
the field, the stall tension, the ceiling and the current limit to set. Every shipped config keeps
the order ceiling < stall tension <= 1.25 x ceiling, and every shipped protocol fits the hardware
template (its dry run passes once a calibration file exists).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

from rig.cli import main
from rig.errors import ConfigError
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, load_rig_config, parse_rig_config
from rig.inputs.servo_ratings import MOTOR_RATINGS, STALL_TENSION_CEILING_RATIO, stall_tension_n

ROOT = Path(__file__).resolve().parent.parent
RIGS = ROOT / "protocols" / "rigs"
SHIPPED_RIGS = [DEFAULT_RIG_CONFIG, *sorted(RIGS.glob("*.yaml")), *sorted(RIGS.glob("*/*.yaml"))]
PROTOCOLS = ["joint_estimation", "joint_estimation_adaptive", "link_validation", "smoke"]


def test_stall_tension_is_torque_constant_times_current_over_radius():
    # XM430-W350: 4.1 N·m at 2.3 A (e-manual); 0.56 A on a 10 mm drum.
    assert stall_tension_n("XM430-W350", 0.56, 0.01) == pytest.approx(4.1 / 2.3 * 0.56 / 0.01)
    assert MOTOR_RATINGS["XM430-W350"].torque_constant_nm_per_a == pytest.approx(1.7826, abs=1e-4)


@pytest.mark.parametrize("path", SHIPPED_RIGS, ids=lambda p: p.stem)
def test_shipped_configs_keep_the_order(path):
    config = load_rig_config(path)
    ceiling = config.limits.force_ceiling_n
    assert ceiling < config.winch_stall_tension_n <= STALL_TENSION_CEILING_RATIO * ceiling


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def test_a_cap_above_the_ratio_is_refused_with_the_current_to_set(tmp_path, capsys):
    text = DEFAULT_RIG_CONFIG.read_text(encoding="utf-8")
    assert "winch_current_limit_a: 0.56" in text
    path = _write(tmp_path, text.replace("winch_current_limit_a: 0.56", "winch_current_limit_a: 1.2"))
    code = main(["run", str(ROOT / "protocols" / "smoke.yaml"), "--rig", str(path), "--dry-run"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert str(path) in err and "limits.winch_current_limit_a" in err
    assert "213.9 N" in err and "80 N = 100.0 N" in err
    advice = re.search(r"at most ([0-9.]+) A", err)
    assert advice is not None and advice.group(1) == "0.560"
    # The advised current passes, and one mA above the ratio does not.
    advised = f"winch_current_limit_a: {advice.group(1)}"
    fixed = _write(tmp_path, text.replace("winch_current_limit_a: 0.56", advised))
    assert load_rig_config(fixed).winch_stall_tension_n <= 100.0
    over = _write(tmp_path, text.replace("winch_current_limit_a: 0.56", "winch_current_limit_a: 0.562"))
    with pytest.raises(ConfigError, match="winch_current_limit_a"):
        load_rig_config(over)


def test_the_check_follows_radius_and_ceiling(tmp_path):
    text = DEFAULT_RIG_CONFIG.read_text(encoding="utf-8")
    # A smaller drum pulls harder at the same current.
    smaller = _write(tmp_path, text.replace("spool_radius_m: 0.01 ", "spool_radius_m: 0.008 "))
    with pytest.raises(ConfigError, match=r"124\.8 N at stall"):
        load_rig_config(smaller)
    # A lower ceiling needs a lower current.
    lower = _write(tmp_path, text.replace("force_ceiling_n: 80.0", "force_ceiling_n: 60.0"))
    with pytest.raises(ConfigError, match=r"at most 0\.420 A"):
        load_rig_config(lower)


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_every_shipped_protocol_fits_the_hardware_template(tmp_path, capsys, protocol):
    # The template names a calibration file that `rig calibrate` writes; any valid one will do.
    calibration = {
        "kind": "rig.loadcell.calibration",
        "version": 1,
        "factor_n_per_count": 1.25e-05,
        "offset_counts": 120000.0,
        "reference_mass_kg": 1.0,
        "g": 9.80665,
        "date": "2026-11-27T00:00:00+00:00",
        "serial": "",
        "format": "rig-lc1",
        "noise_counts": 600.0,
        "temperature_c": None,
    }
    (tmp_path / "loadcell-cal.json").write_text(json.dumps(calibration), encoding="utf-8")
    config = tmp_path / "hardware.yaml"
    config.write_text((RIGS / "hardware.example.yaml").read_text(encoding="utf-8"), encoding="utf-8")
    args = ["run", str(ROOT / "protocols" / f"{protocol}.yaml"), "--rig", str(config), "--dry-run", "--json"]
    assert main(args) == 0, capsys.readouterr().err
    checks = json.loads(capsys.readouterr().out)["limit_checks"]
    assert checks and all(c["ok"] for c in checks)


def test_a_logged_config_is_read_without_the_cap_check(tmp_path):
    # Logs from before the check carry 1.2 A on an 80 N ceiling; replay reads their geometry from the
    # attached config (parse_rig_config), while a config loaded to drive the rig is refused.
    text = DEFAULT_RIG_CONFIG.read_text(encoding="utf-8").replace(
        "winch_current_limit_a: 0.56", "winch_current_limit_a: 1.2"
    )
    logged = parse_rig_config(yaml.safe_load(text), source="rig100.yaml", text=text)
    assert logged.winch_stall_tension_n == pytest.approx(213.9, abs=0.05)
    with pytest.raises(ConfigError, match=r"213\.9 N at stall"):
        load_rig_config(_write(tmp_path, text))
