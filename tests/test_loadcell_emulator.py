"""The load-cell emulator core and its in-process serial transport (virtual time)."""

import math
import random
import statistics

import pytest

from rig.errors import InputError
from rig.hw.loadcell.formats import DeviceReading, IndicatorStCodec, LineDecoder, RigLc1Codec
from rig.sim.loadcell.emulator import FaultPlan, LoadCellEmulator, SignalModel, parse_fault
from rig.sim.loadcell.inprocess_line import InProcessLoadCellSerial
from rig.sim.loadcell.profiles import ConstantTension, SawtoothTension, StepTension, parse_profile
from rig.sim.virtual_clock import VirtualClock


def decode_all(emulator, until_ns, codec=None):
    decoder = LineDecoder(codec or emulator.codec)
    data = b"".join(chunk for _, chunk in emulator.lines_until(until_ns))
    return decoder.feed(data), decoder


def test_signal_chain_gain_offset_noise_and_device_fields():
    signal = SignalModel(
        gain_counts_per_n=1000.0, offset_counts=500.0, drift_counts_per_s=0.0, noise_counts=20.0
    )
    emulator = LoadCellEmulator(ConstantTension(3.0), rate_hz=1000, signal=signal, seed=1)
    lines, _ = decode_all(emulator, 2_000_000_000)
    assert len(lines) == 2001  # samples at 0, 1 ms, ..., 2000 ms
    raws = [ln.raw for ln in lines]
    assert statistics.fmean(raws) == pytest.approx(3500.0, abs=3.0)  # 20/sqrt(2001) ~ 0.45 counts
    assert statistics.pstdev(raws) == pytest.approx(20.0, rel=0.1)
    assert [ln.seq for ln in lines[:3]] == [0, 1, 2]
    assert [ln.device_time_us for ln in lines[:3]] == [0, 1000, 2000]


def test_drift_quantisation_and_saturation():
    signal = SignalModel(
        gain_counts_per_n=1.0e6,
        offset_counts=0,
        drift_counts_per_s=100.0,
        noise_counts=0.0,
        quantisation_counts=64,
        adc_bits=24,
    )
    assert signal.counts(0.0, 10.0, 0.0) == 1024  # 1000 counts of drift, quantised to a multiple of 64
    assert signal.counts(100.0, 0.0, 0.0) == (1 << 23) - 1  # clamped at the ADC's full scale
    assert signal.counts(-100.0, 0.0, 0.0) == -(1 << 23)
    emulator = LoadCellEmulator(ConstantTension(0.0), rate_hz=10, signal=signal)
    lines, _ = decode_all(emulator, 10_000_000_000)
    assert all(ln.raw % 64 == 0 for ln in lines)
    assert lines[-1].raw == 1024


def test_same_seed_same_bytes_different_seed_different_bytes():
    def stream(seed):
        faults = FaultPlan(
            garbage_per_line=0.05, truncate_per_line=0.05, bad_checksum_per_line=0.05, gap_per_line=0.05
        )
        emulator = LoadCellEmulator(SawtoothTension(), rate_hz=500, faults=faults, seed=seed)
        return b"".join(c for _, c in emulator.lines_until(1_000_000_000))

    assert stream(7) == stream(7)
    assert stream(7) != stream(8)


def test_injected_faults_are_all_counted_by_the_decoder():
    emulator = LoadCellEmulator(ConstantTension(1.0), rate_hz=1000, seed=3)
    decoder = LineDecoder(emulator.codec)
    decoder.feed(b"".join(c for _, c in emulator.lines_until(9_000_000)))  # samples 0..9
    emulator.inject_garbage(25)
    emulator.inject_truncated(2)
    decoder.feed(b"".join(c for _, c in emulator.lines_until(19_000_000)))
    emulator.inject_bad_checksum(3)
    emulator.inject_sequence_gap(4)
    decoder.feed(b"".join(c for _, c in emulator.lines_until(39_000_000)))
    emulator.inject_silence(0.1)
    decoder.feed(b"".join(c for _, c in emulator.lines_until(199_000_000)))
    c, e = decoder.counts(), emulator.counts
    assert (e.garbage_bytes, e.truncated_lines, e.bad_checksums, e.gap_samples, e.silenced_samples) == (
        25,
        2,
        3,
        4,
        100,
    )
    assert c.corrupt_lines == 2
    assert c.checksum_failures == 3
    assert c.missing_samples == 2 + 3 + 4 + 100
    assert c.lines_ok == e.lines_sent == 200 - 109
    # Garbage, the truncated fragments and the three checksum-failed lines (>= 20 bytes each) were discarded.
    assert c.bytes_discarded >= 25 + 2 + 3 * 20


def test_random_fault_rates_match_counts():
    faults = FaultPlan(
        garbage_per_line=0.02, truncate_per_line=0.02, bad_checksum_per_line=0.02, gap_per_line=0.01
    )
    emulator = LoadCellEmulator(SawtoothTension(), rate_hz=2000, faults=faults, seed=11)
    lines, decoder = decode_all(emulator, 5_000_000_000)
    c, e = decoder.counts(), emulator.counts
    assert e.truncated_lines > 50 and e.bad_checksums > 50 and e.garbage_bytes > 0 and e.gap_samples > 0
    assert c.corrupt_lines == e.truncated_lines
    assert c.checksum_failures == e.bad_checksums
    assert c.lines_ok == e.lines_sent == len(lines)
    assert c.missing_samples == e.truncated_lines + e.bad_checksums + e.gap_samples


def test_scheduled_silence_sends_nothing_and_seq_keeps_counting():
    emulator = LoadCellEmulator(ConstantTension(0.0), rate_hz=100, faults=FaultPlan(silences_s=((0.5, 0.3),)))
    times = [t for t, _ in emulator.lines_until(1_000_000_000)]
    assert not any(500_000_000 <= t < 800_000_000 for t in times)
    again = LoadCellEmulator(ConstantTension(0.0), rate_hz=100, faults=FaultPlan(silences_s=((0.5, 0.3),)))
    lines, _ = decode_all(again, 1_000_000_000)
    seqs = [ln.seq for ln in lines]
    assert seqs[50] == 80  # 30 samples taken but never sent


def test_indicator_format_shows_kg_and_stability():
    g = 9.80665
    tension = StepTension(0.0)
    emulator = LoadCellEmulator(
        tension,
        format_name="indicator-st",
        rate_hz=50,
        signal=SignalModel(drift_counts_per_s=0.0, noise_counts=50.0),
    )
    lines, _ = decode_all(emulator, 1_000_000_000)
    assert all(ln.unit == "kg" and ln.decimals == 2 and abs(ln.raw) <= 1 for ln in lines)
    tension.set(2.5 * g, 1_000_000_000)
    lines, _ = decode_all(emulator, 3_000_000_000, IndicatorStCodec())
    assert not lines[0].stable  # ringing after the mass went on
    assert lines[-1].stable and lines[-1].raw == pytest.approx(250, abs=1)
    tension.set(200.0, 3_000_000_000)  # beyond the ADC's range
    lines, _ = decode_all(emulator, 3_500_000_000, IndicatorStCodec())
    assert lines[-1].overload


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rate_hz": 5}, "allowed: 10-2000"),
        ({"rate_hz": 2500}, "allowed: 10-2000"),
        ({"rate_hz": 1000, "baud": 115200}, "needs >= 370000 baud"),
        ({"baud": 12345}, "--baud 12345"),
        ({"format_name": "nope"}, "allowed: indicator-st, rig-lc1"),
        ({"format_name": "indicator-st", "faults": FaultPlan(bad_checksum_per_line=0.1)}, "no checksum"),
        ({"format_name": "indicator-st", "faults": FaultPlan(gap_per_line=0.1)}, "no sequence"),
    ],
)
def test_emulator_rejects_bad_parameters(kwargs, match):
    with pytest.raises(InputError, match=match):
        LoadCellEmulator(ConstantTension(0.0), **kwargs)


def test_parse_fault_and_profile():
    plan = parse_fault("silence:1.5:0.25", parse_fault("garbage:0.1", FaultPlan()))
    assert plan.garbage_per_line == 0.1 and plan.silences_s == ((1.5, 0.25),)
    for bad in ("garbage", "garbage:2", "loud:0.1", "silence:1", "silence:1:-1"):
        with pytest.raises(InputError, match="fault"):
            parse_fault(bad, FaultPlan())
    assert parse_profile("constant:4.5")(123) == 4.5
    saw = parse_profile("sawtooth:10:2")
    assert saw(0) == 0.0 and saw(700_000_000) == pytest.approx(5.0)
    assert saw(1_399_000_000) == pytest.approx(9.99, abs=0.02)
    assert saw(1_401_000_000) < 3.1  # the slip
    assert saw(1_900_000_000) == 0.0
    for bad in ("sawtooth:1:0", "constant", "ramp:3"):
        with pytest.raises(InputError, match="--profile"):
            parse_profile(bad)


def test_in_process_serial_delivers_bytes_at_the_baud_rate():
    clock = VirtualClock()
    emulator = LoadCellEmulator(ConstantTension(0.0), rate_hz=10, baud=9600, start_ns=0)
    ser = InProcessLoadCellSerial(emulator, clock)
    line_bytes = len(RigLc1Codec().encode(DeviceReading(120000)))
    clock.advance_ns(1)  # sample 0 taken at t=0 is now on the wire
    assert ser.in_waiting == 0
    byte_ns = 10 * 1e9 / 9600
    clock.advance_to_ns(int(5 * byte_ns) + 1)
    assert ser.in_waiting == 5  # five bytes have crossed the wire
    partial = ser.read(100)
    assert partial == b"$LC,0"
    clock.advance_to_ns(90_000_000)
    rest = ser.readline()
    assert (partial + rest).endswith(b"\r\n") and len(partial + rest) >= line_bytes - 10
    assert ser.read(10) == b""  # nothing more until the next sample at 100 ms


def test_in_process_serial_closed_port_wrong_baud_and_overflow():
    clock = VirtualClock()
    emulator = LoadCellEmulator(ConstantTension(0.0), rate_hz=1000, start_ns=0)
    ser = InProcessLoadCellSerial(emulator, clock, do_not_open=True, rx_buffer_bytes=1000)
    clock.advance_ns(100_000_000)
    ser.open()
    assert ser.in_waiting == 0  # bytes sent while closed are lost
    clock.advance_ns(100_000_000)
    assert ser.in_waiting == 1000 and ser.rx_overflow_bytes > 0
    ser.reset_input_buffer()
    other = LoadCellEmulator(ConstantTension(0.0), rate_hz=1000, start_ns=clock.monotonic_ns())
    wrong = InProcessLoadCellSerial(other, clock, baudrate=115200)
    clock.advance_ns(10_000_000)
    data = wrong.read(wrong.in_waiting)
    assert data and b"\n" not in data and b"$" not in data
    ser.close()
    with pytest.raises(OSError, match="not open"):
        ser.read(1)
    assert ser.write(b"T\r\n") == 3


@pytest.mark.parametrize("rate_hz", [1000.0, 333.0, 2000.0])
def test_fast_path_makes_the_same_bytes_counts_and_draws_as_sample_by_sample(rate_hz):
    def run(fast):
        signal = SignalModel(quantisation_counts=3, adc_bits=20, drift_counts_per_s=1e4)
        emulator = LoadCellEmulator(
            SawtoothTension(peak_n=10.0, period_s=0.7),  # up to saturation at 2**19 counts
            rate_hz=rate_hz,
            signal=signal,
            seed=5,
            start_ns=123_456,
            seq_start=65_000,  # the sequence counter wraps
            device_time_start_us=2**32 - 300_000,  # so does the device clock
        )
        emulator._fault_free_lc1 = fast  # the switch the constructor sets for fault-free rig-lc1
        emulator.inject_silence(0.05, at_ns=200_000_000)
        out = []
        for step in range(1, 200):
            if step == 50:
                emulator.inject_garbage(4)
                emulator.inject_truncated()
                emulator.inject_bad_checksum()
                emulator.inject_sequence_gap(2)
            if step == 120:
                emulator.inject_silence(0.013)
            out += emulator.lines_until(123_456 + step * 7_300_001)
        draws = emulator._rng.getstate(), emulator._spare_normal
        return out, emulator.counts, draws, emulator.next_sample_ns

    fast, slow = run(True), run(False)
    assert fast == slow
    assert fast[1].silenced_samples > 0 and fast[1].truncated_lines == 1


def test_fast_path_only_without_random_faults_and_for_rig_lc1():
    assert LoadCellEmulator(ConstantTension(1.0))._fault_free_lc1
    assert not LoadCellEmulator(ConstantTension(1.0), faults=FaultPlan(gap_per_line=0.01))._fault_free_lc1
    assert not LoadCellEmulator(ConstantTension(1.0), format_name="indicator-st")._fault_free_lc1


def test_fast_path_keeps_the_samples_made_before_the_tension_source_fails():
    def tension(t_ns):
        if t_ns >= 5_000_000:
            raise ValueError("older than the history")
        return 1.0

    emulator = LoadCellEmulator(tension)
    with pytest.raises(ValueError):
        emulator.lines_until(9_000_000)
    assert emulator.counts.samples == emulator.counts.lines_sent == 5
    assert emulator.next_sample_ns == 5_000_000


def test_noise_is_box_muller_pairs_from_the_seeded_random():
    emulator = LoadCellEmulator(ConstantTension(0.0), seed=7)
    draws = [emulator._normal() for _ in range(1001)]
    uniform = random.Random(7).random
    expected = []
    for _ in range(501):  # the algorithm (and so the numbers) of CPython's `random.gauss`
        angle, radius = uniform() * math.tau, math.sqrt(-2.0 * math.log(1.0 - uniform()))
        expected += [math.cos(angle) * radius, math.sin(angle) * radius]
    assert draws == expected[:1001] and emulator._spare_normal == expected[1001]
