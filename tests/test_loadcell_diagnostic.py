"""The load-cell diagnostic (`rig check --only loadcell`): on the simulated rig's cell, on cells labs own,
on made-up recordings for each failing row, over the pty emulator in real time, and on the firmware
under simavr."""

import json

import pytest

from rig.cli import main
from rig.hw.clock import SystemClock
from rig.hw.loadcell.driver import LoadCellStats, SerialLoadCell
from rig.hw.seams import LoadCellSample
from rig.preflight.loadcell import CellListening, clock_skew_ppm, diagnose, listen
from rig.preflight.verdicts import Verdict
from rig.sim.loadcell.emulator import LoadCellEmulator
from rig.sim.loadcell.inprocess_line import ideal_calibration, in_process_serial_factory
from rig.sim.loadcell.profiles import ConstantTension
from rig.sim.virtual_clock import VirtualClock
from rig.vocabulary import LoadCellFormatName
from tests.helpers import build_firmware
from tests.test_loadcell_pty import sim_loadcell
from tests.test_sim_scenarios import SCENARIOS

CHECKS = (
    "load cell answers",
    "banner",
    "rate",
    "jitter",
    "noise (counts)",
    "noise (newtons)",
    "unique values",
    "saturation",
    "gaps and damaged lines",
    "clock skew",
)
# `rig check`'s loadcell section adds the stale timeout against the measured rate.
SECTION_CHECKS = (*CHECKS, "stale timeout holds the sample period")


def check_json(capsys, *args):
    code = main(["check", "--only", "loadcell", "--json", "--window-s", "3", *args])
    return code, json.loads(capsys.readouterr().out)


def by_check(rows):
    return {row["check"]: row for row in rows}


def test_the_simulated_rigs_cell_passes_with_its_banner(capsys):
    code, out = check_json(capsys)
    rows = by_check(out["rows"])
    assert code == 0 and tuple(rows) == SECTION_CHECKS
    # The built-in simulated cell boots as firmware/rig_hx711 does: its banner, with its rate.
    banner = rows["banner"]
    assert banner["verdict"] == "pass"
    assert banner["measured"] == "#BOOT fw=rig-sim/1.0.0 adc=emulated gain=A128 sps=1000 period-us=1000"
    assert (
        rows["rate"]["verdict"] == "pass"
        and "1000.00 samples/s measured, 1000 configured" in rows["rate"]["measured"]
    )
    assert (
        rows["noise (newtons)"]["measured"].startswith(("4.", "5."))
        and "mN" in rows["noise (newtons)"]["measured"]
    )
    assert all(rows[c]["verdict"] == "pass" for c in CHECKS)


def test_an_hx711_at_10_per_s_with_a_slow_resonator_and_a_dtr_reset(capsys):
    code, out = check_json(capsys, "--rig", str(SCENARIOS / "cell-hx711-10.yaml"), "--window-s", "30")
    rows = by_check(out["rows"])
    assert code == 0
    assert rows["banner"]["verdict"] == "pass" and rows["banner"]["measured"].startswith("#BOOT")
    assert "first sample 1.9" in rows["load cell answers"]["measured"]  # 1.5 s reset + 0.4 s settling
    assert rows["noise (counts)"]["measured"].startswith(("19.", "20.", "21.", "22.", "23."))
    skew = rows["clock skew"]
    assert skew["verdict"] == "warn" and "slow" in skew["measured"]
    assert 2500 <= int(skew["measured"].split()[0]) <= 3500  # the scenario's resonator: 3000 ppm slow


def test_a_polled_gauge_is_diagnosed_without_device_clock_or_banner(capsys):
    code, out = check_json(capsys, "--rig", str(SCENARIOS / "cell-gauge-12.yaml"))
    rows = by_check(out["rows"])
    assert code == 0 and rows["rate"]["verdict"] == "pass"
    assert "not sent" in rows["banner"]["measured"] and "stamped on receipt" in rows["clock skew"]["measured"]


def test_bad_input_is_one_line_and_exit_2(capsys):
    assert main(["check", "--only", "loadcell", "--window-s", "0"]) == 2
    assert capsys.readouterr().err.strip() == "rig: error: --window-s 0.0: allowed: 1 to 600"


def sample(k, raw, rate_hz=80.0):
    t_ns = round(k * 1e9 / rate_hz)
    return LoadCellSample(t_ns, raw, raw * 1e-5, k % 65536, (t_ns // 1000) % 2**32)


def listening(samples, receipts=None, stats=None, **kwargs):
    options = {
        "port": "/dev/ttyUSB0",
        "format": LoadCellFormatName.RIG_LC1,
        "window_s": 5.0,
        "samples": tuple(samples),
        "receipt_ns": tuple(receipts or [s.time_ns for s in samples]),
        "stats": stats or LoadCellStats(0, len(samples), 0, 0, 0, 0, 0, 0, 0),
        "factor_n_per_count": 1e-5,
        "configured_rate_hz": 80.0,
        "baud": 115200,
    }
    return CellListening(**{**options, **kwargs})


def verdicts(heard):
    return {row.check: row.verdict for row in diagnose(heard)}


def test_each_failing_finding_gets_its_row_and_fix():
    healthy = [sample(k, 1000 + (k * 7919) % 97) for k in range(400)]
    assert verdicts(listening(healthy))["saturation"] is Verdict.PASS
    saturated = healthy[:-5] + [sample(k, (1 << 23) - 1) for k in range(395, 400)]
    assert verdicts(listening(saturated))["saturation"] is Verdict.FAIL
    stuck = [sample(k, 1234) for k in range(400)]
    assert verdicts(listening(stuck))["unique values"] is Verdict.FAIL
    damaged = LoadCellStats(20_000, 400, 3, 2, 120, 4, 9, 0, 0)
    row = next(r for r in diagnose(listening(healthy, stats=damaged)) if r.check == "gaps and damaged lines")
    assert row.verdict is Verdict.FAIL and "9 missing in 4 gaps, 3 garbled, 2 bad checksums" in row.measured
    assert "baud" in row.fix
    assert verdicts(listening(healthy, configured_rate_hz=10.0))["rate"] is Verdict.FAIL
    noisy = [sample(k, (k * 7919) % 200_000) for k in range(400)]
    assert verdicts(listening(noisy))["noise (newtons)"] is Verdict.FAIL
    assert verdicts(listening(healthy, factor_n_per_count=None))["noise (newtons)"] is Verdict.WARN
    restarted = LoadCellStats(20_000, 400, 0, 0, 0, 0, 0, 0, 0, info_lines=2, restarts=1)
    assert verdicts(listening(healthy, stats=restarted))["restarts"] is Verdict.FAIL
    silent = diagnose(listening(healthy[:3], failure="no valid sample for 3.1 s"))
    assert [(r.check, r.verdict) for r in silent] == [("load cell answers", Verdict.FAIL)]
    assert "loadcell.baud (115200)" in silent[0].fix


def test_clock_skew_from_the_lower_envelope():
    # Device clock 2 % slow: the host sees its samples drift later; reads every 16 ms.
    samples = [sample(k, 0) for k in range(800)]
    receipts = [((round(s.time_ns * 1.02) // 16_000_000) + 1) * 16_000_000 for s in samples]
    assert clock_skew_ppm(samples, receipts) == pytest.approx(20_000, rel=0.01)
    heard = listening(samples, receipts=receipts)
    assert verdicts(heard)["clock skew"] is Verdict.FAIL


def test_listen_reports_what_stopped_it():
    clock = VirtualClock()
    emulator = LoadCellEmulator(ConstantTension(0.0), rate_hz=80, baud=921600, start_ns=clock.monotonic_ns())
    emulator.inject_silence(100.0, at_ns=clock.monotonic_ns() + 2_000_000_000)
    driver = SerialLoadCell(
        "sim",
        baud=921600,
        clock=clock,
        calibration=ideal_calibration(emulator),
        stale_timeout_s=0.2,
        serial_factory=in_process_serial_factory(emulator, clock),
    )
    heard = listen(driver, clock, 5.0)
    assert "no valid sample for" in heard.failure and not driver.is_open
    rows = {r.check: r for r in diagnose(heard)}
    assert (
        rows["load cell answers"].verdict is Verdict.FAIL
        and "stopped during the window" in rows["load cell answers"].fix
    )


def test_over_the_pty_emulator_in_real_time(tmp_path):
    args = (
        "--cell",
        "hx711-80",
        "--baud",
        "115200",
        "--clock-error-ppm",
        "-8000",
        "--fault",
        "truncate:0.01",
    )
    with sim_loadcell(tmp_path, *args) as (link, _):
        driver = SerialLoadCell(str(link), baud=115200, rate_hz=80, stale_timeout_s=2.0)
        heard = listen(driver, SystemClock(), 6.0)
    rows = {r.check: r for r in diagnose(heard)}
    assert rows["load cell answers"].verdict is Verdict.PASS
    assert rows["rate"].verdict is Verdict.PASS  # 80/s by the device's own clock
    assert rows["gaps and damaged lines"].verdict is Verdict.FAIL  # 1 % of lines cut short
    assert rows["noise (newtons)"].verdict is Verdict.WARN  # no calibration given
    skew = rows["clock skew"]
    assert skew.verdict is Verdict.WARN and "slow" in skew.measured
    assert 5000 <= int(skew.measured.split()[0]) <= 11_000  # 8000 ppm, measured over 6 s of real time


def test_the_firmware_under_simavr(tmp_path):
    from tests.test_firmware_simavr import HARNESS, _harness_process, _missing_tools

    missing = _missing_tools()
    if missing:
        pytest.skip(f"firmware toolchain or simavr missing: {missing}")
    build = build_firmware()
    assert build.returncode == 0, build.stderr[-2000:]
    # The harness runs --fast (simulated time outpaces the host's, so the clock skew row is not
    # checked) and waits for its reader; a generous stale timeout rides out a busy machine.
    harness_args = ("--rate", "80", "--signal", "ramp:-5000:5000:7")
    with _harness_process(HARNESS, tmp_path, *harness_args) as (_, link):
        driver = SerialLoadCell(str(link), baud=115200, rate_hz=80, stale_timeout_s=5.0)
        heard = listen(driver, SystemClock(), 4.0)
    rows = {r.check: r for r in diagnose(heard)}
    assert rows["load cell answers"].verdict is Verdict.PASS, rows["load cell answers"]
    assert rows["banner"].verdict is Verdict.PASS and rows["banner"].measured.startswith(
        "#BOOT fw=rig-hx711/"
    )
    assert rows["rate"].verdict is Verdict.PASS and rows["saturation"].verdict is Verdict.PASS
    assert rows["gaps and damaged lines"].verdict is Verdict.PASS
    assert rows["unique values"].verdict is Verdict.PASS


def test_a_silent_cell_at_another_baud_is_told_what_the_firmware_sends() -> None:
    silent = diagnose(listening([], baud=921600, failure="no valid sample for 3.1 s"))
    assert (
        "loadcell.baud (921600; the project's firmware (firmware/rig_hx711) sends at 115200)" in silent[0].fix
    )
