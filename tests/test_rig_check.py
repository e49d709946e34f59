"""`rig check` on the simulated rig: every check passes on the built-in rig, and each fails the way it should.

The failing cases use the simulator's knobs (a loaded line, a winch wound the other way, the emulated
servos' voltage, temperature, firmware and hardware error, a silent or slow load cell) and files
standing in for a port and its latency timer.
"""

from __future__ import annotations

import io
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from rig.hw.dxl.bus import DynamixelServoBus, ServoHealthReport, ServoInfo
from rig.inputs.rig_config import load_rig_config
from rig.preflight.check_context import CheckContext, CheckDevices, CheckOptions
from rig.preflight.config_update import updated_text
from rig.preflight.jog import fitted_slope
from rig.preflight.port_checks import check_port, latency_row
from rig.preflight.sections import run_sections
from rig.preflight.servos import servo_checks
from rig.preflight.verdicts import CheckRow, Verdict
from rig.sim.simulated_rig import SimulatedRig, simulated_rig

pytestmark = pytest.mark.slow


def _rows(rows: list[CheckRow], check: str) -> list[CheckRow]:
    return [r for r in rows if check in r.check]


def _one(rows: list[CheckRow], check: str) -> CheckRow:
    (row,) = _rows(rows, check)
    return row


def _check_sim(
    config_path: Path | None = None,
    poke: Callable[[SimulatedRig], None] = lambda rig: None,
    only: tuple[str, ...] = (),
    **options: Any,
) -> list[CheckRow]:
    """Run the sections on a simulated rig after `poke` changed its emulators."""
    config = load_rig_config(config_path)
    sim = simulated_rig(config)
    poke(sim)
    session = sim.session
    assert isinstance(session.servos, DynamixelServoBus)
    devices = CheckDevices(session.servos, session.load_cell, session.clock, calibrated=True)
    ctx = CheckContext(config, CheckOptions(**options), lambda: devices)
    rows = run_sections(ctx, only)
    assert not any(s.torque_enabled for s in sim.devices.bus.servos), "a check left torque on"
    return rows


def _sim_config(write_file: Callable[[str, str], Path], body: str, name: str = "rig.yaml") -> Path:
    return write_file("extends: simulated\n" + body, name)


# ------------------------------------------------------------------------------------------ CLI


def test_built_in_rig_passes_every_check(cli_json: Callable[..., Any]) -> None:
    out = cli_json("check", "--json")
    assert out["rig_kind"] == "simulated"
    sections = {row["section"] for row in out["rows"]}
    assert sections == {"ports", "servos", "loadcell", "line", "limits"}  # no move without --move
    assert out["counts"]["fail"] == 0
    failed = [row for row in out["rows"] if row["verdict"] != "pass"]
    # The built-in rig names no cell capacity (a warning). Its emulated cell boots with the
    # firmware's banner when the port opens, as a real board does.
    assert [row["check"] for row in failed] == ["load cell capacity"]


def test_exit_codes(run_cli: Callable[..., Any], write_file: Callable[[str, str], Path]) -> None:
    assert run_cli("check", "--only", "limits").code == 0
    loaded = _sim_config(write_file, "simulation: {initial_tension_n: 12}\n")
    result = run_cli("check", "--rig", loaded, "--only", "line")
    assert result.code == 1
    assert "FAIL" in result.out and "slacken the line" in result.out
    assert run_cli("check", "--rig", write_file("kind: nonsense\n", "bad.yaml")).code == 2
    assert run_cli("check", "--write").code == 2  # --write needs --move
    with pytest.raises(SystemExit) as exited:  # argparse's own refusal
        run_cli("check", "--only", "nonsense")
    assert exited.value.code == 2


def test_only_runs_the_named_sections(cli_json: Callable[..., Any]) -> None:
    out = cli_json("check", "--only", "ports", "limits", "--json")
    assert {row["section"] for row in out["rows"]} == {"ports", "limits"}


# ------------------------------------------------------------------------------------------ ports


def test_port_missing_fails_with_the_by_id_advice(tmp_path: Path) -> None:
    (row,) = check_port("servo bus", str(tmp_path / "ttyUSB9"), tmp_path)
    assert row.verdict is Verdict.FAIL
    assert "no such device" in row.measured and "/dev/serial/by-id" in row.fix


def test_port_not_permitted_names_the_group(tmp_path: Path) -> None:
    port = tmp_path / "ttyUSB0"
    port.write_text("")
    rows = check_port("servo bus", str(port), tmp_path, access=lambda path, mode: False)
    permission = _one(rows, "permission")
    assert permission.verdict is Verdict.FAIL
    assert "usermod -aG" in permission.fix and "99-rig.rules" in permission.fix
    allowed = _one(check_port("servo bus", str(port), tmp_path), "permission")
    assert allowed.verdict is Verdict.PASS if os.access(port, os.R_OK | os.W_OK) else Verdict.FAIL
    # A ttyUSB name can swap with another adapter's on a reboot.
    assert _one(rows, "port name").verdict is Verdict.WARN


@pytest.mark.parametrize(
    ("latency_ms", "verdict"), [(1, Verdict.PASS), (4, Verdict.WARN), (16, Verdict.FAIL)]
)
def test_latency_timer(tmp_path: Path, latency_ms: int, verdict: Verdict) -> None:
    timer = tmp_path / "bus" / "usb-serial" / "devices" / "ttyUSB0" / "latency_timer"
    timer.parent.mkdir(parents=True)
    timer.write_text(f"{latency_ms}\n")
    row = latency_row("servo bus", "ttyUSB0", tmp_path)
    assert row.verdict is verdict
    assert f"{latency_ms} ms" in row.measured
    if verdict is not Verdict.PASS:
        assert "99-rig.rules" in row.fix and "udevadm" in row.fix


def test_no_latency_timer_is_not_an_ftdi_port(tmp_path: Path) -> None:
    assert latency_row("load cell", "ttyACM0", tmp_path).verdict is Verdict.PASS


def test_shipped_udev_rule_sets_one_millisecond() -> None:
    rule = Path(__file__).parent.parent / "docs" / "udev" / "99-rig.rules"
    lines = [line for line in rule.read_text().splitlines() if line and not line.startswith("#")]
    assert any('ATTR{latency_timer}="1"' in line and "ftdi_sio" in line for line in lines)


# ------------------------------------------------------------------------------------------ servos


def test_servos_found_with_model_firmware_and_health() -> None:
    rows = _check_sim(only=("servos",))
    assert all(r.verdict is Verdict.PASS for r in rows), rows
    assert _one(rows, "servo 1 (winch) model").measured.startswith("XM430-W350")
    assert "mode 5" in _one(rows, "servo 1 (winch) operating mode").measured


def test_missing_servo_fails_with_scan_advice() -> None:
    rows = _check_sim(poke=lambda rig: rig.devices.bus.set_silent(2), only=("servos",))
    (row,) = rows
    assert row.verdict is Verdict.FAIL and "missing" in row.measured
    assert "rig scan" in row.fix and "Wizard" in row.fix
    assert "`rig setup-servos --rig " in row.fix  # the rig's own tool first (docs/hardware.md §4)


def _set_winch(**attributes: Any) -> Callable[[SimulatedRig], None]:
    def poke(rig: SimulatedRig) -> None:
        servo = rig.devices.bus.servo(1)
        for name, value in attributes.items():
            if name == "temperature_c":
                servo.set_temperature_c(value)
            elif name == "hardware_error":
                rig.devices.bus.set_hardware_error(1, value)
            else:
                setattr(servo, name, value)

    return poke


@pytest.mark.parametrize(
    ("knob", "check", "verdict", "words"),
    [
        ({"supply_voltage_v": 9.0}, "input voltage", Verdict.FAIL, "10-14.8 V"),
        ({"supply_voltage_v": 15.5}, "input voltage", Verdict.FAIL, "10-14.8 V"),
        ({"temperature_c": 70}, "temperature", Verdict.WARN, "cool"),
        ({"temperature_c": 80}, "temperature", Verdict.FAIL, "cool"),
        ({"hardware_error": 0x20}, "hardware error", Verdict.FAIL, "reboot"),
    ],
)
def test_winch_health_failures(knob: dict[str, Any], check: str, verdict: Verdict, words: str) -> None:
    rows = _check_sim(poke=_set_winch(**knob), only=("servos",))
    row = _one(rows, f"servo 1 (winch) {check}")
    assert row.verdict is verdict, row
    assert words in row.fix + row.measured
    assert _one(rows, f"servo 2 (bender) {check}").verdict is Verdict.PASS


def test_old_firmware() -> None:
    def firmware(version: int) -> Callable[[SimulatedRig], None]:
        def poke(rig: SimulatedRig) -> None:
            servo = rig.devices.bus.servo(1)
            servo.firmware = version
            servo._set("Firmware Version", version)

        return poke

    no_watchdog = _one(_check_sim(poke=firmware(37), only=("servos",)), "servo 1 (winch) firmware")
    assert no_watchdog.verdict is Verdict.FAIL and "v38" in no_watchdog.measured
    assert "Firmware Update" in no_watchdog.fix
    slow_read = _one(_check_sim(poke=firmware(44), only=("servos",)), "servo 1 (winch) firmware")
    assert slow_read.verdict is Verdict.WARN and "v45" in slow_read.measured


def test_winch_model_without_current_control_fails_the_mode_check() -> None:
    info = ServoInfo(1, "winch", "XL430-W250", 1060, 48)
    health = ServoHealthReport(1, 11.1, 30.0, 0, 0)
    row = _one(servo_checks(info, health), "operating mode")
    assert row.verdict is Verdict.FAIL and "mode 5" in row.measured


# ------------------------------------------------------------------------------------------ load cell, line


def test_silent_load_cell_fails(write_file: Callable[[str, str], Path]) -> None:
    config = _sim_config(write_file, "simulation: {faults: [{device: loadcell, kind: silent, at_s: 0}]}\n")
    rows = _check_sim(config, only=("loadcell", "line"))
    answers = _one(rows, "load cell answers")
    assert answers.verdict is Verdict.FAIL and "no valid sample" in answers.measured
    assert _one(rows, "line slack").verdict is Verdict.FAIL


def test_slow_cell_against_the_stale_timeout(write_file: Callable[[str, str], Path]) -> None:
    # An explicit 0.2 s (left out, the timeout follows the rate and holds 5 periods).
    config = _sim_config(write_file, "limits: {stale_timeout_s: 0.2}\nsimulation: {loadcell_rate_hz: 10}\n")
    rows = _check_sim(config, only=("loadcell",))
    assert [r.verdict for r in rows if r.check == "rate"] == [Verdict.PASS]
    row = _one(rows, "stale timeout")
    assert row.verdict is Verdict.FAIL and "stale_timeout_s" in row.fix


def test_loaded_line_fails_and_reads_the_tension(write_file: Callable[[str, str], Path]) -> None:
    config = _sim_config(write_file, "simulation: {initial_tension_n: 12}\n")
    row = _one(_check_sim(config, only=("line",)), "line slack")
    assert row.verdict is Verdict.FAIL
    assert float(row.measured.split(" N")[0]) > 2.0  # beyond limits.zero_tolerance_n


# ------------------------------------------------------------------------------------------ limits


def test_tension_cap_is_a_row_with_the_current_to_set(
    write_file: Callable[[str, str], Path], run_cli: Callable[..., Any]
) -> None:
    config = _sim_config(write_file, "limits: {force_ceiling_n: 80, winch_current_limit_a: 1.2}\n")
    result = run_cli("check", "--rig", config, "--only", "limits", "--json")
    assert result.code == 1  # a row, where `rig run` refuses the config (exit 2)
    out = result.data
    (row,) = [r for r in out["rows"] if "stall tension" in r["check"]]
    assert row["verdict"] == "fail"
    assert "set winch_current_limit_a to at most 0.560 A" in row["fix"]


def test_load_cell_capacity(write_file: Callable[[str, str], Path]) -> None:
    small = _sim_config(write_file, "loadcell: {capacity_n: 90}\n", "small.yaml")
    rows = _check_sim(small, only=("limits",))
    assert _one(rows, "force ceiling < load cell capacity").verdict is Verdict.PASS
    assert _one(rows, "winch stall tension < load cell capacity").verdict is Verdict.FAIL  # 99.8 N
    large = _sim_config(write_file, "loadcell: {capacity_n: 200}\n", "large.yaml")
    assert all(r.verdict is Verdict.PASS for r in _check_sim(large, only=("limits",)))


def test_protocol_ceiling_above_the_rig(
    run_cli: Callable[..., Any], write_file: Callable[[str, str], Path]
) -> None:
    config = _sim_config(write_file, "limits: {force_ceiling_n: 60, winch_current_limit_a: 0.42}\n")
    result = run_cli("check", "--rig", config, "--only", "limits", "--protocol", "protocols/smoke.yaml")
    assert result.code == 1
    assert "protocol force ceiling <= rig force ceiling" in result.out


# ------------------------------------------------------------------------------------------ move


def test_jog_passes_and_measures_the_stiffness() -> None:
    config = load_rig_config()
    sim = simulated_rig(config)
    truth_n_per_m = sim.devices.world.preset.effective_line_stiffness_n_per_m
    rows = _check_sim(only=("move",), move=True)
    assert _one(rows, "reel direction").verdict is Verdict.PASS
    stiffness = _one(rows, "line stiffness")
    assert stiffness.verdict is Verdict.PASS
    measured = float(stiffness.measured.split(" N/m")[0])
    assert measured == pytest.approx(truth_n_per_m, rel=0.05)


def test_no_jog_without_move() -> None:
    assert _check_sim(only=("move",)) == []


def test_jog_refuses_a_loaded_line(write_file: Callable[[str, str], Path]) -> None:
    config = _sim_config(write_file, "simulation: {initial_tension_n: 12}\n")
    (row,) = _check_sim(config, only=("move",), move=True)
    assert row.verdict is Verdict.FAIL and "not started" in row.measured


def test_reversed_winch_is_found_and_written(
    write_file: Callable[[str, str], Path], run_cli: Callable[..., Any]
) -> None:
    config = _sim_config(write_file, "name: reversed\nsimulation: {winch_reversed: true}\n")
    before = config.read_text()
    result = run_cli("check", "--rig", config, "--move", "--only", "move")
    assert result.code == 1
    assert "set reel_direction: -1" in result.out
    assert config.read_text() == before  # nothing written without --write or a yes
    result = run_cli("check", "--rig", config, "--move", "--only", "move", "--write")
    assert "wrote reel_direction: -1" in result.out
    assert load_rig_config(config).reel_direction == -1
    assert run_cli("check", "--rig", config, "--move", "--only", "move").code == 0


def test_at_a_terminal_the_measurement_is_shown_before_the_question_and_a_rerun_asked_for_after(
    write_file: Callable[[str, str], Path], run_cli: Callable[..., Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    config = _sim_config(write_file, "name: reversed\nsimulation: {winch_reversed: true}\n")

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    def answer_yes(question: str) -> str:
        print(f"<asked: {question}>")
        return "y"

    monkeypatch.setattr(sys, "stdin", Terminal())
    monkeypatch.setattr("builtins.input", answer_yes)
    result = run_cli("check", "--rig", config, "--move", "--only", "move")
    asked = result.out.index("<asked: Write what the jog measured (reel_direction: -1)")
    assert result.out.index("set reel_direction: -1") < asked  # the row with the measurement came first
    assert load_rig_config(config).reel_direction == -1
    after = result.out[asked:]
    assert "wrote reel_direction: -1" in after and "NOT ready" in after
    assert f"run `rig check --rig {config} --move` again" in after


def test_config_edit_keeps_comments_and_replaces_in_place() -> None:
    text = "name: x\nspool_radius_m: 0.01   # drum\nreel_direction: 1   # which way\nkind: hardware\n"
    new = updated_text(text, {"reel_direction": "-1", "line_stiffness_n_per_m": "212"})
    assert new.splitlines() == [
        "name: x",
        "spool_radius_m: 0.01   # drum",
        "line_stiffness_n_per_m: 212  # measured by rig check --move",
        "reel_direction: -1  # which way",
        "kind: hardware",
    ]


def test_stiffness_fit() -> None:
    points = [(0.001 * i, 200.0 * 0.001 * i + 0.3) for i in range(10)]
    assert fitted_slope(points) == pytest.approx(200.0)
    assert fitted_slope(points[:2]) is None
    assert fitted_slope([(0.0, 1.0), (0.0, 2.0), (0.0, 3.0)]) is None


def test_wrong_model_fails_the_handshake(write_file: Callable[[str, str], Path]) -> None:
    # The config names an XL430-W250 bender; the bus has an XM430-W350 at ID 2.
    config = _sim_config(
        write_file,
        "servos:\n  ids: [{id: 1, role: winch}, {id: 2, role: bender, model: XL430-W250}]\n"
        "simulation:\n  servo_models: [XM430-W350, XM430-W350]\n",
    )
    (row,) = _check_sim(config, only=("servos",))
    assert row.verdict is Verdict.FAIL and "wrong model" in row.measured and "XL430-W250" in row.measured
    # The fix is the config's model (or another servo), not a scan for servos that did answer.
    assert f"set servos.ids[1].model: XM430-W350 in {config}" in row.fix and "rig scan" not in row.fix


def test_nominal_stiffness_far_from_the_line_warns_and_is_written(
    write_file: Callable[[str, str], Path], run_cli: Callable[..., Any]
) -> None:
    config = _sim_config(write_file, "line_stiffness_n_per_m: 50000\n")
    result = run_cli("check", "--rig", config, "--move", "--only", "move", "--write", "--json")
    assert result.code == 0  # a warning
    (row,) = [r for r in result.data["rows"] if r["check"] == "line stiffness"]
    assert row["verdict"] == "warn" and "line_stiffness_n_per_m" in row["fix"]
    (written,) = result.data["written"]
    assert written.startswith("line_stiffness_n_per_m: ")
    assert load_rig_config(config).line_stiffness_n_per_m == pytest.approx(5000, rel=0.05)


def test_simulation_keys_make_the_servo_checks_fail(
    write_file: Callable[[str, str], Path], cli_json: Callable[..., Any], run_cli: Callable[..., Any]
) -> None:
    config = _sim_config(
        write_file, "simulation: {servo_supply_v: 9.0, servo_temperature_c: 85, servo_firmware: 37}\n"
    )
    result = run_cli("check", "--rig", config, "--only", "servos", "--json")
    assert result.code == 1
    verdicts = {row["check"]: row["verdict"] for row in result.data["rows"]}
    for servo in ("servo 1 (winch)", "servo 2 (bender)"):
        assert verdicts[f"{servo} input voltage"] == "fail"
        assert verdicts[f"{servo} temperature"] == "fail"
        assert verdicts[f"{servo} firmware"] == "fail"
    defaults = cli_json("check", "--only", "servos", "--json")
    assert {row["verdict"] for row in defaults["rows"]} == {"pass"}
