"""Load-cell benchmarks.

1. Parsing: rig-lc1 lines per second through the driver (`SerialLoadCell.poll()`: split, checksum,
   decode, sequence check, calibrate, `LoadCellSample`) from an in-memory stream, against a bare
   `readline()` loop over the same bytes (`io.BytesIO`), in the same run.
2. Streaming: `rig sim loadcell` in its own process on a pty at --rate Hz, read by the driver
   through real pyserial for --duration-s; lines expected vs received, gaps and corrupt lines. Both
   ends at 921600 baud (the emulator's default; the driver's is the firmware's 115200, too slow for
   1000 lines/s).
3. Simulated chain: what one sample costs the main thread of a simulated run, in CPU time: the
   emulator (1 kHz, default signal, a sawtooth tension), the in-process port and the driver's
   `poll()`, with the virtual clock advanced as the runner does (two 10 ms advances per poll).

Run: .venv/bin/python benchmarks/bench_loadcell.py [--lines N] [--duration-s 60] [--rate 1000]
     [--chain-s 20] [--smoke]
"""

from __future__ import annotations

import argparse
import io
import select
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from model.gravity import STANDARD_GRAVITY_M_S2
from rig.hw.loadcell.calibration import Calibration
from rig.hw.loadcell.driver import SerialLoadCell
from rig.hw.loadcell.formats import DeviceReading, RigLc1Codec
from rig.sim.loadcell.inprocess_line import simulated_load_cell
from rig.sim.loadcell.profiles import SawtoothTension
from rig.sim.virtual_clock import VirtualClock

PTY_BAUD = 921_600
CAL = Calibration(1.25e-5, 120000.0, None, STANDARD_GRAVITY_M_S2, "2026-01-01", "", "rig-lc1")


class MemoryPort:
    """A port whose whole input is already buffered: measures the driver, not the transport."""

    def __init__(self, data: bytes) -> None:
        self._data = data
        self._pos = 0
        self.chunk = 4096  # what one OS read typically returns

    @property
    def in_waiting(self) -> int:
        return min(self.chunk, len(self._data) - self._pos)

    def read(self, n: int) -> bytes:
        out = self._data[self._pos : self._pos + n]
        self._pos += len(out)
        return out

    def reset_input_buffer(self) -> None:
        pass

    def close(self) -> None:
        pass


def make_stream(n_lines: int) -> bytes:
    codec = RigLc1Codec()
    return b"".join(
        codec.encode(DeviceReading(120000 + (k * 7919) % 400000, k, 1000 * k)) for k in range(n_lines)
    )


def bench_parse(n_lines: int, repeats: int) -> dict[str, float]:
    data = make_stream(n_lines)
    driver_best = readline_best = plain_best = float("inf")
    for _ in range(repeats):
        port = MemoryPort(data)
        driver = SerialLoadCell(
            "mem",
            calibration=CAL,
            stale_timeout_s=1e9,
            clock=VirtualClock(),
            queue_samples=n_lines,
            serial_factory=lambda mem=port, **_: mem,
        )
        driver.open()
        t0 = time.perf_counter()
        received = 0
        while port.in_waiting:
            received += len(driver.poll())
        driver_best = min(driver_best, time.perf_counter() - t0)
        assert received == n_lines and driver.stats().lines_ok == n_lines

        stream = io.BytesIO(data)
        t0 = time.perf_counter()
        count = 0
        for _line in iter(stream.readline, b""):
            count += 1
        readline_best = min(readline_best, time.perf_counter() - t0)
        assert count == n_lines

        # The same decode written plainly: readline, split, checksum loop, int().
        stream = io.BytesIO(data)
        t0 = time.perf_counter()
        values = []
        for line in iter(stream.readline, b""):
            body, _, tail = line[1:].partition(b"*")
            checksum = 0
            for byte in body:
                checksum ^= byte
            if checksum == int(tail[:2], 16):
                _, seq, t_us, raw = body.split(b",")
                values.append((int(seq), int(t_us), int(raw)))
        plain_best = min(plain_best, time.perf_counter() - t0)
        assert len(values) == n_lines
    return {
        "lines": n_lines,
        "driver_lines_per_s": n_lines / driver_best,
        "readline_lines_per_s": n_lines / readline_best,
        "plain_parse_lines_per_s": n_lines / plain_best,
        "driver_time_over_readline": driver_best / readline_best,
        "driver_time_over_plain_parse": driver_best / plain_best,
    }


def bench_chain(rig_s: float, repeats: int) -> dict[str, float]:
    """CPU microseconds per sample of emulator + in-process port + driver poll, median and best."""
    per_sample_us = []
    for _ in range(repeats):
        clock = VirtualClock()
        driver, _emulator = simulated_load_cell(SawtoothTension(), clock, seed=0)
        driver.open()
        received = 0
        t0 = time.thread_time()
        for _ in range(round(rig_s * 50)):
            clock.advance_ns(10_000_000)
            clock.advance_ns(10_000_000)
            received += len(driver.poll())
        per_sample_us.append((time.thread_time() - t0) / received * 1e6)
        assert received >= rig_s * 1000 - 1 and driver.stats().lines_ok == received
    tension = SawtoothTension()
    t0 = time.thread_time()
    for k in range(round(rig_s * 1000)):
        tension(k * 1_000_000)
    return {
        "samples": received,
        "median_us_per_sample": statistics.median(per_sample_us),
        "best_us_per_sample": min(per_sample_us),
        "tension_source_us_per_sample": (time.thread_time() - t0) / (rig_s * 1000) * 1e6,
    }


def bench_pty(duration_s: float, rate_hz: float) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        link = Path(tmp) / "loadcell"
        cmd = [sys.executable, "-c", "import sys; from rig.cli import main; sys.exit(main(sys.argv[1:]))"]
        proc = subprocess.Popen(
            [*cmd, "sim", "loadcell", "--link", str(link), "--rate", f"{rate_hz:g}", "--baud", str(PTY_BAUD)],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        try:
            ready, _, _ = select.select([proc.stdout], [], [], 30.0)
            if not ready or not proc.stdout.readline().startswith("PTY "):
                raise RuntimeError("rig sim loadcell did not start")
            driver = SerialLoadCell(str(link), baud=PTY_BAUD, calibration=CAL, stale_timeout_s=1.0)
            received = 0
            first_seq = last_seq = None
            with driver:
                end = time.monotonic() + duration_s
                while time.monotonic() < end:
                    samples = driver.poll()
                    if samples:
                        received += len(samples)
                        first_seq = samples[0].seq if first_seq is None else first_seq
                        last_seq = samples[-1].seq
                    time.sleep(0.01)
                received += len(driver.poll())
            stats = driver.stats()
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=10)
    # Expected: every sequence number from the first received to the last (16-bit wrap undone).
    expected = received + stats.missing_samples
    span = ((last_seq - first_seq) % 65536 + 1) if first_seq is not None else 0
    return {
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "lines_received": received,
        "lines_expected": expected,
        "lines_expected_from_rate": round(duration_s * rate_hz),
        "seq_span_mod_65536": span,
        "sequence_gaps": stats.sequence_gaps,
        "missing_samples": stats.missing_samples,
        "corrupt_lines": stats.corrupt_lines,
        "checksum_failures": stats.checksum_failures,
        "samples_dropped": stats.samples_dropped,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--lines", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--duration-s", type=float, default=60.0)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--skip-pty", action="store_true")
    parser.add_argument("--chain-s", type=float, default=20.0, help="rig seconds per chain repetition")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.lines, args.repeats, args.chain_s, args.duration_s, args.skip_pty = 2_000, 1, 1.0, 0.3, False
    chain = bench_chain(args.chain_s, max(args.repeats, 5))
    print(
        f"chain: {chain['samples']} samples: emulator + in-process port + driver poll "
        f"{chain['median_us_per_sample']:.2f} us CPU/sample "
        f"(median; best {chain['best_us_per_sample']:.2f}), "
        f"of which the tension source {chain['tension_source_us_per_sample']:.2f}"
    )
    parse = bench_parse(args.lines, args.repeats)
    print(
        f"parse: {parse['lines']} rig-lc1 lines: driver {parse['driver_lines_per_s']:,.0f} lines/s, "
        f"bare readline {parse['readline_lines_per_s']:,.0f} lines/s, "
        f"driver time / readline time = {parse['driver_time_over_readline']:.1f}; "
        f"plain readline+split+checksum+int {parse['plain_parse_lines_per_s']:,.0f} lines/s, "
        f"driver time / plain-parse time = {parse['driver_time_over_plain_parse']:.2f}"
    )
    if not args.skip_pty:
        r = bench_pty(args.duration_s, args.rate)
        print(
            f"pty: {r['rate_hz']:g} Hz for {r['duration_s']:g} s: received {r['lines_received']} lines, "
            f"expected {r['lines_expected']} (by sequence numbers; "
            f"{r['lines_expected_from_rate']} by rate x time), "
            f"gaps {r['sequence_gaps']}, missing {r['missing_samples']}, corrupt {r['corrupt_lines']}, "
            f"checksum failures {r['checksum_failures']}, dropped from queue {r['samples_dropped']}"
        )
        if not r["lines_received"]:
            raise SystemExit("pty: the driver received no line")


if __name__ == "__main__":
    main()
