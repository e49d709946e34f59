"""Servos as labs have them: every supported model's facts as data, its table, and the winch's restriction."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.errors import ConfigError
from rig.hw.dxl.control_table import MODELS, MODELS_BY_NUMBER, model_name_for, table_for_model
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, load_rig_config
from rig.inputs.servo_ratings import MOTOR_RATINGS, PROTOCOL_1_MODELS, stall_tension_n, winch_models
from rig.sim.settings import load_checked_rig_config
from rig.vocabulary import ServoModel


def test_every_model_has_its_facts_and_a_table_that_agrees():
    numbers = [MOTOR_RATINGS[m].model_number for m in ServoModel]
    assert len(set(numbers)) == len(numbers) and 0 not in numbers
    assert not set(numbers) & set(PROTOCOL_1_MODELS)  # a number tells the protocol
    for model in ServoModel:
        rating, table = MOTOR_RATINGS[model], MODELS[model]
        assert table.model_number == rating.model_number == table["Model Number"].default
        assert rating.source.startswith("https://emanual.robotis.com/docs/en/dxl/")
        assert 0 < rating.min_voltage_v < 12.0 <= rating.max_voltage_v
        assert rating.stall_torque_nm > 0 and rating.stall_current_a > 0 and rating.no_load_speed_rad_s > 0
        # Current sensing is the current registers, and the current-based position mode.
        sensing = rating.current_sensing
        assert (
            ("Present Current" in table) == ("Goal Current" in table) == ("Current Limit" in table) == sensing
        )
        assert (5 in table.operating_modes) == sensing == rating.current_based_position
        assert (
            table["Velocity Limit"].default * 0.229 <= rating.no_load_speed_rad_s * 60 / (2 * 3.14159) + 0.5
        )


def test_an_xm430_w210_is_recognised_by_its_number():
    assert model_name_for(1030) == "XM430-W210"
    table = table_for_model(1030)
    assert table is MODELS_BY_NUMBER[1030] and table.stall_torque_nm == 3.0
    assert MOTOR_RATINGS[ServoModel.XM430_W210].current_sensing


def test_an_xm430_w210_winch_connects_on_the_emulated_bus(emulated_dxl):
    rig = emulated_dxl(ids=(1, 2), model="XM430-W210")
    rig.driver.connect()
    info = rig.driver.info()
    assert info[1].model == "XM430-W210" and info[1].model_number == 1030
    assert rig.driver.read_states()[1].current_a == pytest.approx(0.0, abs=0.05)


def test_the_winch_must_have_current_based_position_control(tmp_path):
    text = DEFAULT_RIG_CONFIG.read_text(encoding="utf-8")
    winch = "{id: 1, role: winch, model: XM430-W350}"
    assert winch in text
    for model in ("XC430-W240", "XL430-W250", "MX-28(2.0)"):
        path = tmp_path / "rig.yaml"
        path.write_text(text.replace(winch, f"{{id: 1, role: winch, model: {model}}}"))
        with pytest.raises(ConfigError, match=r"servos\.ids\[0\]\.model: .*no current-based position") as err:
            load_rig_config(path)
        assert "XM430-W210" in str(err.value)  # the allowed models are named
    assert ServoModel.XM540_W270 in winch_models() and ServoModel.XC430_W240 not in winch_models()


def test_an_xm430_w210_winch_is_a_valid_config_with_its_own_stall_tension(tmp_path):
    text = DEFAULT_RIG_CONFIG.read_text(encoding="utf-8")
    path = tmp_path / "rig.yaml"
    path.write_text(
        text.replace("{id: 1, role: winch, model: XM430-W350}", "{id: 1, role: winch, model: XM430-W210}")
    )
    config = load_rig_config(path)
    assert config.servos.winch.model == ServoModel.XM430_W210
    assert config.winch_stall_tension_n == pytest.approx(stall_tension_n(ServoModel.XM430_W210, 0.56, 0.01))
    assert config.winch_stall_tension_n == pytest.approx(3.0 / 2.3 * 0.56 / 0.01)


@pytest.mark.parametrize("devices", ["byte", "object"])
def test_the_simulated_rig_serves_every_configured_servo_its_own_model(tmp_path, cli_json, devices):
    # A winch XM430-W350 and a bender XM430-W210 on one bus: each emulated as configured (before,
    # every servo took the winch's model and the bender failed the handshake as the wrong model).
    rig = tmp_path / "mixed.yaml"
    rig.write_text(
        "extends: simulated\nname: mixed\nservos:\n  ids:\n"
        "    - {id: 1, role: winch, model: XM430-W350}\n"
        "    - {id: 2, role: bender, model: XM430-W210}\n",
        encoding="utf-8",
    )
    protocol = Path(__file__).resolve().parent.parent / "protocols" / "smoke.yaml"
    out = cli_json("run", protocol, "--rig", rig, "--devices", devices, "--out", tmp_path / "o", "--json")
    assert out["completed"] == 2 and out["reason"] is None


def test_simulation_servo_models_are_one_per_configured_servo(tmp_path):
    rig = tmp_path / "r.yaml"
    rig.write_text("extends: simulated\nsimulation:\n  servo_models: [XM430-W350]\n", encoding="utf-8")
    with pytest.raises(
        ConfigError, match=r"r\.yaml: simulation\.servo_models: 1 models; allowed: one per servo"
    ):
        load_checked_rig_config(rig)
    rig.write_text("extends: simulated\nsimulation:\n  servo_models: [XM430-W350, AX-12]\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"simulation\.servo_models\[1\]: 'AX-12'; allowed: XM430-W350"):
        load_checked_rig_config(rig)
