"""Cells as labs have them (issue 21): settling, DTR reset and boot grace, clock error, polled gauges,
the baud/rate table and the stale timeout's default, on the in-process emulator (virtual time)."""

import math

import pytest
import yaml

from rig.errors import ConfigError, StaleDataError
from rig.hw.loadcell.formats import FORCE_UNITS_N
from rig.inputs.rig_config import default_stale_timeout_s, load_rig_config, parse_rig_config
from rig.sim.loadcell.emulator import LoadCellEmulator
from rig.sim.loadcell.inprocess_line import simulated_load_cell
from rig.sim.loadcell.profiles import ConstantTension
from rig.sim.settings import SIMULATED_CELLS, check_simulation, require_simulated
from rig.sim.virtual_clock import VirtualClock
from rig.vocabulary import LOADCELL_FORMAT_TRAITS, LoadCellFormatName
from tests.test_sim_scenarios import CELL_NAMES, SCENARIOS


def read_for(driver, clock, seconds, step_s=0.01):
    samples = []
    for _ in range(round(seconds / step_s)):
        clock.sleep(step_s)
        samples += driver.poll()
    return samples


def cell_driver(name, clock, tension_n=5.0, **kwargs):
    cell = SIMULATED_CELLS[name]
    return simulated_load_cell(
        ConstantTension(tension_n),
        clock,
        format_name=LoadCellFormatName(cell.format),
        rate_hz=cell.rate_hz,
        cell=cell,
        baud=921600,
        **kwargs,
    )


@pytest.mark.parametrize("name", [n for n, c in SIMULATED_CELLS.items() if c is not None])
def test_each_cell_reads_the_tension_at_its_rate_after_settling(name):
    clock = VirtualClock()
    cell = SIMULATED_CELLS[name]
    driver, _ = cell_driver(name, clock)
    start_ns = clock.monotonic_ns()
    with driver:
        samples = read_for(driver, clock, 5.0)
    assert abs(len(samples) - 5.0 * cell.rate_hz) <= 0.05 * 5.0 * cell.rate_hz + 2
    first_s = (samples[0].time_ns - driver._anchor_ns - start_ns) / 1e9
    assert first_s >= cell.settling_s  # nothing before the converter has settled
    forces = [s.force_n for s in samples]
    resolution_n = (
        FORCE_UNITS_N[cell.gauge_unit] * 10**-cell.gauge_decimals if cell.format == "value-unit" else 0
    )
    assert abs(sum(forces) / len(forces) - 5.0) < 0.002 + resolution_n
    if cell.format == "rig-lc1":
        assert driver.banner is not None and driver.banner.text.startswith("BOOT")
        noise_counts = math.sqrt(
            sum((s.raw - sum(x.raw for x in samples) / len(samples)) ** 2 for s in samples) / len(samples)
        )
        assert 0.6 * cell.noise_counts < noise_counts < 1.5 * cell.noise_counts


def test_hx711_counts_and_noise_follow_the_datasheet():
    hx10, hx80 = SIMULATED_CELLS["hx711-10"], SIMULATED_CELLS["hx711-80"]
    # 10 mV at 49.03 N over 2.384 nV a count; 50 nV and 90 nV RMS input noise.
    assert hx10.counts_per_n == pytest.approx(10e6 / 49.03 / (20e6 / 2**23))
    assert hx10.noise_counts == pytest.approx(50 / (20e6 / 2**23)) and round(hx10.noise_counts) == 21
    assert round(hx80.noise_counts) == 38 and hx10.settling_s == 0.4 and hx80.settling_s == 0.05


def test_a_rate_change_settles_before_the_next_sample():
    emulator = LoadCellEmulator(ConstantTension(1.0), rate_hz=10, settling_s=0.05, start_ns=0)
    before = emulator.lines_until(1_000_000_000)
    emulator.change_rate(80, 1_000_000_000)
    after = emulator.lines_until(2_000_000_000)
    assert [t for t, _ in before] == [50_000_000 + k * 100_000_000 for k in range(10)]
    assert after[0][0] == 1_050_000_000  # 50 ms of settling, then 80/s
    assert after[1][0] - after[0][0] == 12_500_000 and len(after) == 77


def test_dtr_reset_is_silent_then_the_banner_and_the_boot_grace_covers_it():
    clock = VirtualClock()
    driver, _ = cell_driver("hx711-80", clock, dtr_reset_s=1.5, stale_timeout_s=0.2)
    start_ns = clock.monotonic_ns()
    with driver:
        samples = read_for(driver, clock, 3.0)
    first_s = (samples[0].time_ns - driver._anchor_ns - start_ns) / 1e9
    assert 1.5 + 0.05 <= first_s < 1.5 + 0.05 + 0.02  # the reset, the settling, then the first sample
    assert samples[0].seq == 0 and driver.banner is not None
    assert driver.stats().missing_samples == 0
    # Without the grace (shorter than the reset), the run stops with a message that says why.
    clock = VirtualClock()
    driver, _ = cell_driver("hx711-80", clock, dtr_reset_s=1.5, stale_timeout_s=0.2, boot_grace_s=1.0)
    with (
        driver,
        pytest.raises(
            StaleDataError,
            match=r"after opening the port, beyond the boot grace of 1 s \(nothing valid came\)",
        ),
    ):
        read_for(driver, clock, 3.0)


@pytest.mark.parametrize("clock_error_ppm", [-10_000, 10_000])
def test_a_clock_one_percent_off_is_stamped_within_a_sample_period(clock_error_ppm):
    clock = VirtualClock()
    driver, emulator = cell_driver("hx711-80", clock, clock_error_ppm=clock_error_ppm)
    with driver:
        samples = read_for(driver, clock, 600.0, step_s=0.05)
    period_ns = 1e9 / 80
    errors = [
        abs(s.time_ns - driver._anchor_ns - emulator.sample_time_ns(s.seq + 65536 * (i // 65536)))
        for i, s in enumerate(samples)
    ]
    assert max(errors[-800:]) < period_ns
    assert driver.device_clock_skew_ppm == pytest.approx(-clock_error_ppm, rel=0.05)


def test_the_driver_polls_a_gauge_and_reads_newtons():
    clock = VirtualClock()
    driver, emulator = cell_driver("gauge-12", clock, tension_n=-83.5376)  # -18.78 lbf
    with driver:
        samples = read_for(driver, clock, 2.0)
    assert 22 <= len(samples) <= 25 and emulator.counts.polls == driver.polls_sent
    assert {s.raw for s in samples} <= {round(-v * 4.4482216152605e6) for v in (18.77, 18.78, 18.79)}
    assert all(s.seq is None and s.device_time_us is None for s in samples)
    # Unpolled, the gauge says nothing: the driver's staleness stops the run.
    clock = VirtualClock()
    driver, emulator = cell_driver("gauge-12", clock)
    driver.poll_command = None
    with driver, pytest.raises(StaleDataError):
        read_for(driver, clock, 4.0)
    assert emulator.counts.lines_sent == 0


@pytest.mark.parametrize("name", CELL_NAMES)
def test_cell_scenarios_load_with_their_rates_and_timeouts(name):
    config = load_rig_config(SCENARIOS / f"{name}.yaml")
    cell = require_simulated(config).cell
    assert cell is not None
    assert config.loadcell.rate_hz == cell.rate_hz and config.loadcell.format == cell.format
    assert config.limits.stale_timeout_s == default_stale_timeout_s(cell.rate_hz)
    assert cell.rate_hz <= LOADCELL_FORMAT_TRAITS[config.loadcell.format].max_rate_hz(config.loadcell.baud)


HARDWARE = """
kind: hardware
spool_radius_m: 0.01
servos: {port: /dev/null, ids: [{id: 1, role: winch}]}
loadcell: {port: /dev/ttyUSB0, %s}
article:
  joint_radius_m: 0.01
  segment_lengths_m: [0.03]
  load: {point_m: [0, 0, 0.03], direction: [0, -1, 0]}
limits: {force_ceiling_n: 80, winch_current_limit_a: 0.5}
"""


def hardware(loadcell):
    return parse_rig_config(yaml.safe_load(HARDWARE % loadcell), source="r.yaml")


def test_the_baud_rate_table_is_enforced_at_config_time():
    config = hardware("rate_hz: 80")
    assert config.loadcell.baud == 115200 and config.limits.stale_timeout_s == 0.2
    assert hardware("rate_hz: 10").limits.stale_timeout_s == 0.5
    assert hardware("rate_hz: 10").loadcell.boot_grace_s == 3.0
    with pytest.raises(
        ConfigError,
        match=r"^r\.yaml: loadcell\.rate_hz: 1000 lines/s of rig-lc1 .*allowed: rate_hz 0\.1-311.3 at this",
    ):
        hardware("rate_hz: 1000")
    assert hardware("rate_hz: 1000, baud: 921600").limits.stale_timeout_s == 0.2
    with pytest.raises(
        ConfigError, match=r"^r\.yaml: loadcell\.rate_hz: required for the polled format value-unit"
    ):
        hardware("format: value-unit")
    with pytest.raises(ConfigError, match=r"^r\.yaml: loadcell\.boot_grace_s: .*allowed"):
        hardware("rate_hz: 10, boot_grace_s: 60")
    assert hardware("format: value-unit, rate_hz: 12, baud: 9600").loadcell.rate_hz == 12


def test_a_simulated_cell_needs_its_format_and_rate():
    base = "extends: simulated\nsimulation: {loadcell_cell: hx711-10, loadcell_rate_hz: %s}"
    with pytest.raises(
        ConfigError,
        match=r"simulation\.loadcell_rate_hz: 80; allowed: 10, the rate of loadcell_cell hx711-10",
    ):
        check_simulation(parse_rig_config(yaml.safe_load(base % 80), source="r.yaml"))
    gauge = "extends: simulated\nsimulation: {loadcell_cell: gauge-12, loadcell_rate_hz: 12}"
    with pytest.raises(ConfigError, match=r"loadcell\.format: rig-lc1; allowed: value-unit"):
        check_simulation(parse_rig_config(yaml.safe_load(gauge), source="r.yaml"))


def test_rig_calibrate_works_on_a_polled_gauge(tmp_path, capsys):
    from rig.cli import main
    from rig.hw.loadcell.calibration import Calibration

    out = tmp_path / "cal.json"
    args = ["calibrate", "--sim", "--format", "value-unit", "--rate", "12", "--baud", "9600"]
    code = main([*args, "--reference-kg", "2", "--yes", "--settle-s", "0.5", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    calibration = Calibration.load(out)
    assert calibration.format == "value-unit"
    assert calibration.factor_n_per_count == pytest.approx(1e-6, rel=0.005)  # micronewtons, as sent


def test_a_gauge_polled_over_the_pty_in_real_time(tmp_path):
    import time

    from rig.hw.loadcell.driver import SerialLoadCell
    from tests.test_loadcell_pty import sim_loadcell

    args = ("--cell", "gauge-12", "--baud", "9600", "--profile", "constant:-83.5376")
    with sim_loadcell(tmp_path, *args) as (link, _):
        driver = SerialLoadCell(
            str(link), baud=9600, format_name="value-unit", rate_hz=12, stale_timeout_s=2.0
        )
        samples = []
        with driver:
            end = time.monotonic() + 2.0
            while time.monotonic() < end:
                samples += driver.poll()
                time.sleep(0.01)
    assert 15 <= len(samples) <= 26 and driver.polls_sent >= len(samples)
    assert {s.raw for s in samples} <= {round(-v * 4.4482216152605e6) for v in (18.77, 18.78, 18.79)}
