"""The pyserial load-cell driver against the in-process emulator (virtual time) and pyserial's loop://."""

import itertools
import math
import statistics
import time

import pytest
import serial

from rig.errors import InputError, NotConnectedError, StaleDataError
from rig.hw.loadcell.calibration import indicator_calibration
from rig.hw.loadcell.device_time import OFFSET_LEAK_NS
from rig.hw.loadcell.driver import SerialLoadCell
from rig.hw.loadcell.formats import DeviceReading, RigLc1Codec
from rig.hw.seams import LineStatsSource, LoadCell, LoadCellLineStats
from rig.sim.loadcell.emulator import FaultPlan, LoadCellEmulator, SignalModel
from rig.sim.loadcell.inprocess_line import in_process_serial_factory, simulated_load_cell
from rig.sim.loadcell.profiles import ConstantTension, SawtoothTension
from rig.sim.virtual_clock import VirtualClock


def run_for(load_cell, clock, seconds, step_s=0.01):
    samples = []
    for _ in range(round(seconds / step_s)):
        clock.sleep(step_s)
        samples += load_cell.poll()
    return samples


def test_driver_implements_the_seam_and_reads_calibrated_force():
    clock = VirtualClock()
    driver, emulator = simulated_load_cell(SawtoothTension(peak_n=20.0, period_s=2.0), clock, rate_hz=500)
    assert isinstance(driver, LoadCell)
    with driver:
        samples = run_for(driver, clock, 2.0)
    assert len(samples) == emulator.counts.samples - 1  # the last line is still on the wire
    assert [s.seq for s in samples] == list(range(len(samples)))
    assert samples[100].device_time_us == 200_000
    truth = SawtoothTension(peak_n=20.0, period_s=2.0)
    errors = [s.force_n - truth(round(s.device_time_us * 1000)) for s in samples]
    assert statistics.fmean(errors) == pytest.approx(0.0, abs=0.002)  # drift 5 counts/s -> < 0.2 mN
    assert statistics.pstdev(errors) == pytest.approx(400 / 80_000, rel=0.1)  # the noise, 5 mN
    # Sampling times: the device clock mapped onto the host's, so samples read in one poll keep
    # the device's 2 ms spacing, and no stamp is later than the poll (every 10 ms) that read it.
    anchor_ns = clock.time_ns() - clock.monotonic_ns()
    steady = samples[5:]  # the first poll's lines teach the mapping its latency
    steps = {b.time_ns - a.time_ns for a, b in itertools.pairwise(steady)}
    # The spacing holds up to the offset estimate's small moves (its leak, then a new minimum).
    assert all(abs(step - 2_000_000) <= 5 * OFFSET_LEAK_NS for step in steps)
    first_poll_ns = anchor_ns + 10_000_000
    assert first_poll_ns - 10_000_000 < samples[0].time_ns <= first_poll_ns
    assert max(s.force_n for s in samples) == pytest.approx(20.0, abs=0.1)
    stats = driver.stats()
    assert (stats.lines_ok, stats.corrupt_lines, stats.checksum_failures, stats.missing_samples) == (
        len(samples),
        0,
        0,
        0,
    )


def test_every_injected_fault_is_counted_by_the_driver():
    clock = VirtualClock()
    driver, emulator = simulated_load_cell(ConstantTension(5.0), clock, rate_hz=1000, seed=5)
    driver.open()
    run_for(driver, clock, 0.1)
    emulator.inject_garbage(40)
    emulator.inject_truncated(3)
    emulator.inject_bad_checksum(2)
    emulator.inject_sequence_gap(7)
    run_for(driver, clock, 0.1)
    emulator.inject_silence(0.2)
    run_for(driver, clock, 0.4)  # 0.2 s silence < 0.5 s stale timeout: no error
    stats = driver.stats()
    assert stats.corrupt_lines == 3
    assert stats.checksum_failures == 2
    # The dropped, truncated and corrupted samples are consecutive: one gap of 12, then the silence's.
    assert stats.sequence_gaps == 2
    assert stats.missing_samples == 3 + 2 + 7 + 200
    assert stats.bytes_discarded >= 40 + 3 + 2 * 20
    assert stats.lines_ok == emulator.counts.lines_sent - 1  # last line still on the wire
    assert stats.samples_dropped == 0


def test_line_stats_count_lost_lines_and_give_per_trial_deltas():
    clock = VirtualClock()
    driver, emulator = simulated_load_cell(ConstantTension(5.0), clock, rate_hz=1000, seed=5)
    assert isinstance(driver, LineStatsSource)
    driver.open()
    run_for(driver, clock, 0.1)
    before = driver.line_stats()
    # The one information line is the emulated board's boot banner.
    assert (
        before == LoadCellLineStats(len_ok := before.lines_ok, 0, 0, 0, 0, 0, info_lines=1) and len_ok >= 99
    )
    assert before.lossless
    emulator.inject_truncated(3)
    emulator.inject_bad_checksum(2)
    emulator.inject_sequence_gap(7)
    received = run_for(driver, clock, 0.1)
    emulator.inject_silence(0.05)
    received += run_for(driver, clock, 0.2)
    after = driver.line_stats()
    trial = after.since(before)
    # The truncated, corrupted and dropped samples are consecutive: one gap of 12; then the silence's 50.
    assert trial == LoadCellLineStats(
        lines_ok=len(received),
        checksum_failures=2,
        garbled_lines=3,
        missing_samples=3 + 2 + 7 + 50,
        sequence_gaps=2,
        samples_dropped=0,
    )
    assert not trial.lossless
    assert trial.as_dict()["missing_samples"] == 62
    assert trial.describe().startswith(f"{len(received)} lines ok; 62 samples missing in 2 sequence gaps, ")
    stats = driver.stats()  # the same counts as the diagnostics
    assert (stats.lines_ok, stats.corrupt_lines, stats.checksum_failures) == (
        after.lines_ok,
        after.garbled_lines,
        after.checksum_failures,
    )
    driver.close()
    driver.open()  # counters restart: a delta across a reopen is the counts since it
    run_for(driver, clock, 0.05)
    reopened = driver.line_stats()
    assert reopened.missing_samples == 0 and reopened.since(after) == reopened


def test_random_faults_from_a_plan_match_emulator_counts():
    clock = VirtualClock()
    plan = FaultPlan(
        garbage_per_line=0.01, truncate_per_line=0.01, bad_checksum_per_line=0.01, gap_per_line=0.005
    )
    driver, emulator = simulated_load_cell(SawtoothTension(), clock, rate_hz=2000, faults=plan, seed=2)
    with driver:
        samples = run_for(driver, clock, 3.0)
    stats, sent = driver.stats(), emulator.counts
    assert stats.corrupt_lines == sent.truncated_lines > 0
    assert stats.checksum_failures == sent.bad_checksums > 0
    assert len(samples) == stats.lines_ok
    assert stats.missing_samples == sent.truncated_lines + sent.bad_checksums + sent.gap_samples


def test_stale_error_within_the_timeout_after_silence_then_recovery():
    clock = VirtualClock()
    driver, emulator = simulated_load_cell(ConstantTension(1.0), clock, rate_hz=1000, stale_timeout_s=0.25)
    driver.open()
    received = run_for(driver, clock, 0.5)
    emulator.inject_silence(1.0)
    silence_start_ns = emulator.next_sample_ns
    raised_at_ns = None
    for _ in range(200):
        clock.sleep(0.01)
        try:
            received += driver.poll()
        except StaleDataError as exc:
            raised_at_ns = clock.monotonic_ns()
            message = str(exc)
            break
    assert raised_at_ns is not None
    # Ages count from the receipt of the last sample (at the poll that read it, within 10 ms of
    # its sampling time, which is what the sample carries).
    last_sampled_ns = received[-1].time_ns - (clock.time_ns() - clock.monotonic_ns())
    assert last_sampled_ns >= silence_start_ns - 2_000_000
    assert 0.25 < (raised_at_ns - last_sampled_ns) / 1e9 <= 0.25 + 0.02  # within two poll periods
    assert "limit 0.25 s" in message and "no valid sample for 0.2" in message
    assert driver.is_stale and driver.last_sample_age_s > 0.25
    with pytest.raises(StaleDataError):
        driver.poll()  # keeps raising while stale: never papered over
    clock.advance_to_ns(silence_start_ns + 1_000_000_000 + 5_000_000)
    resumed = driver.poll()
    assert resumed and not driver.is_stale
    assert driver.stats().missing_samples == 1000


def test_stale_when_nothing_ever_arrives_at_the_wrong_baud():
    clock = VirtualClock()
    emulator = LoadCellEmulator(ConstantTension(0.0), baud=921600, start_ns=0)
    driver = SerialLoadCell(
        "sim",
        baud=460800,
        clock=clock,
        stale_timeout_s=0.2,
        boot_grace_s=0.3,
        serial_factory=in_process_serial_factory(emulator, clock),
    )
    driver.open()
    assert run_for(driver, clock, 0.3) == []
    clock.sleep(0.02)
    with pytest.raises(StaleDataError, match=r"no valid sample for 0\.32.*boot grace of 0\.3 s") as raised:
        driver.poll()
    # The lab's case: a rig-lc1 cell at a baud the project's firmware does not send.
    assert "baud rate (460800; the project's firmware (firmware/rig_hx711) sends at 115200)" in str(
        raised.value
    )
    stats = driver.stats()
    assert stats.lines_ok == 0 and stats.bytes_discarded > 0


def test_sequence_and_device_time_kept_as_sent_across_wraps():
    clock = VirtualClock()
    emulator = LoadCellEmulator(
        ConstantTension(0.0), rate_hz=1000, seq_start=65530, device_time_start_us=(1 << 32) - 3000, start_ns=0
    )
    driver = SerialLoadCell(
        "sim", baud=921600, clock=clock, serial_factory=in_process_serial_factory(emulator, clock)
    )
    driver.open()
    samples = run_for(driver, clock, 0.02)
    assert [s.seq for s in samples[:8]] == [65530, 65531, 65532, 65533, 65534, 65535, 0, 1]
    assert [s.device_time_us for s in samples[:5]] == [
        (1 << 32) - 3000,
        (1 << 32) - 2000,
        (1 << 32) - 1000,
        0,
        1000,
    ]
    assert math.isnan(samples[0].force_n)  # no calibration: raw only
    assert driver.stats().missing_samples == 0


def test_indicator_format_through_the_driver():
    clock = VirtualClock()
    g = 9.80665
    driver, _ = simulated_load_cell(
        ConstantTension(1.23 * g),
        clock,
        format_name="indicator-st",
        rate_hz=50,
        signal=SignalModel(noise_counts=0.0, drift_counts_per_s=0.0),
    )
    assert driver.calibration == indicator_calibration("kg", 2, serial="sim", date=driver.calibration.date)
    with driver:
        samples = run_for(driver, clock, 1.0)
    assert len(samples) >= 45
    assert all(s.raw == 123 and s.seq is None and s.device_time_us is None for s in samples)
    assert samples[-1].force_n == pytest.approx(1.23 * g)
    assert driver.stats().missing_samples == 0


def test_queue_bound_drops_oldest_and_counts():
    clock = VirtualClock()
    emulator = LoadCellEmulator(ConstantTension(0.0), rate_hz=1000, start_ns=0)
    driver = SerialLoadCell(
        "sim",
        baud=921600,
        clock=clock,
        queue_samples=100,
        stale_timeout_s=10.0,
        serial_factory=in_process_serial_factory(emulator, clock),
    )
    driver.open()
    clock.sleep(0.5)  # ~500 lines waiting in the port buffer, read in one poll
    samples = driver.poll()
    assert len(samples) == 100
    assert driver.stats().samples_dropped == driver.stats().lines_ok - 100 > 300
    assert samples[-1].seq == driver.stats().lines_ok - 1  # newest kept


def test_not_open_bad_parameters_and_failing_port():
    driver = SerialLoadCell("sim", clock=VirtualClock())
    with pytest.raises(NotConnectedError, match="not open"):
        driver.poll()
    for kwargs, match in [
        ({"stale_timeout_s": 0}, "stale_timeout_s"),
        ({"format_name": "x"}, "allowed"),
        ({"reader": "async"}, "reader"),
        ({"queue_samples": 0}, "queue_samples"),
    ]:
        with pytest.raises(InputError, match=match):
            SerialLoadCell("sim", **kwargs)

    class Unplugged:
        def __init__(self, **_):
            pass

        in_waiting = property(lambda self: (_ for _ in ()).throw(OSError(5, "Input/output error")))

        def reset_input_buffer(self):
            pass

        def close(self):
            pass

    driver = SerialLoadCell("/dev/ttyUSB9", clock=VirtualClock(), serial_factory=Unplugged)
    driver.open()
    with pytest.raises(NotConnectedError, match="Input/output error"):
        driver.poll()
    driver.close()
    driver.close()  # idempotent


def test_threaded_reader_on_pyserial_loop_url_real_time():
    """A real pyserial object (loop://) selects the reader thread; stale detection in real time."""
    ports = []

    def factory(port, baudrate, timeout):
        ser = serial.serial_for_url(port, baudrate=baudrate, timeout=timeout)
        ports.append(ser)
        return ser

    codec = RigLc1Codec()
    driver = SerialLoadCell(
        "loop://", stale_timeout_s=0.2, serial_factory=factory, calibration=indicator_calibration("N", 0)
    )
    with driver:
        assert driver._thread is not None and driver._thread.is_alive()
        ports[0].write(b"".join(codec.encode(DeviceReading(k, k, 1000 * k)) for k in range(50)))
        samples, deadline = [], time.monotonic() + 5.0
        while len(samples) < 50 and time.monotonic() < deadline:
            samples += driver.poll()
            time.sleep(0.01)
        assert [s.raw for s in samples] == list(range(50))
        assert samples[7].force_n == 7.0
        last_receipt_ns = samples[-1].time_ns
        with pytest.raises(StaleDataError):
            while time.monotonic() < deadline:
                driver.poll()
                time.sleep(0.01)
        assert 0.2 < (driver.clock.time_ns() - last_receipt_ns) / 1e9 < 1.0
    assert driver._thread is None and not ports[0].is_open


def test_close_and_reopen_on_the_in_process_port():
    clock = VirtualClock()
    driver, _ = simulated_load_cell(ConstantTension(2.0), clock, rate_hz=200)
    driver.open()
    first = run_for(driver, clock, 0.2)
    driver.close()
    assert not driver.is_open
    clock.sleep(1.0)  # lines sent while closed are lost
    driver.open()
    second = run_for(driver, clock, 0.2)
    assert len(first) >= 38 and len(second) >= 38
    assert second[0].seq > first[-1].seq + 190  # the device kept counting while the port was closed
    assert driver.stats().missing_samples == 0  # counters restart at open()


def test_a_restart_is_logged_counted_and_mapped_afresh_not_a_sequence_gap(caplog):
    clock = VirtualClock()
    driver, emulator = simulated_load_cell(ConstantTension(5.0), clock, rate_hz=500)
    with driver, caplog.at_level("INFO", logger="rig.hw.loadcell.driver"):
        before = run_for(driver, clock, 1.0)
        emulator.inject_restart()  # the firmware's reset: the banner, then seq and clock from 0
        after = run_for(driver, clock, 1.0)
        info = driver.info_lines()
        stats = driver.line_stats()
    samples = before + after
    restart = next(i for i, s in enumerate(samples) if s.seq == 0 and i > 0)
    assert [s.seq for s in samples[restart:]] == list(range(len(samples) - restart))
    assert samples[restart].device_time_us == 0
    # Two banners: the boot's (not a restart: no sample before it) and the restart's.
    assert (stats.restarts, stats.info_lines, stats.sequence_gaps, stats.missing_samples) == (1, 2, 0, 0)
    assert not stats.lossless and "restarted 1 times" in stats.describe()
    assert driver.stats().restarts == 1
    assert [(i.banner, i.restart) for i in info] == [(True, False), (True, True)]
    assert any(r.levelname == "WARNING" and "restarted" in r.getMessage() for r in caplog.records)
    # The restarted clock is mapped afresh: sample times run on across the restart (mapped with
    # the old offset, the samples after it would be stamped a second in the past). As after open(),
    # the first read's lines share its receipt time until the mapping has learnt the latency.
    steps = [b.time_ns - a.time_ns for a, b in itertools.pairwise(samples)]
    assert min(steps[5:]) >= 0
    assert 0 <= steps[restart - 1] <= 20_000_000


def test_a_banner_before_the_first_sample_is_information_only():
    clock = VirtualClock()
    emulator = LoadCellEmulator(ConstantTension(1.0), rate_hz=100, banner=b"#BOOT fw=test\r\n")
    driver = SerialLoadCell(
        "sim://loadcell", baud=921600, clock=clock, serial_factory=in_process_serial_factory(emulator, clock)
    )
    with driver:
        samples = run_for(driver, clock, 0.5)
        stats = driver.line_stats()
    assert samples and samples[0].seq == 0
    assert (stats.info_lines, stats.restarts, stats.garbled_lines) == (1, 0, 0) and stats.lossless
    assert [i.text for i in driver.info_lines()] == ["BOOT fw=test"]
    assert emulator.counts.banners == 1
    with pytest.raises(InputError, match="banner"):
        LoadCellEmulator(ConstantTension(1.0), format_name="indicator-st", rate_hz=10, banner=b"#BOOT\r\n")
