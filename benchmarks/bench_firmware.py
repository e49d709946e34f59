"""Load-cell firmware targets (issue 20), measured on the built image under simavr.

For each rate, the image (firmware/build/rig_hx711.elf) runs in firmware/build/hx711-sim with the
HX711 model, `--fast`, and the rig's `SerialLoadCell` reads the pty, as tests/test_firmware_simavr.py
does. Reported per rate:

* lost conversions: sequence gaps and missing samples the driver counted, and conversions the model
  completed but the firmware never read (`missed_conversions`);
* line-to-line t-us spacing against the model's period (min/max step, largest difference);
* the latency the firmware adds, in simulated microseconds: from the model's data-ready edge to the
  stop bit of the line's last byte (the harness's UART tap; simavr paces the UART at 11 bit times
  a byte, one more than 8N1 needs, so real hardware is a little faster);
* simulated seconds per wall second.

And once: flash and static RAM use of the image (`make -s -C firmware size`).

Run: .venv/bin/python benchmarks/bench_firmware.py [--samples 10000] [--rates 80,10,320] [--json]
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from rig.hw.loadcell.driver import SerialLoadCell

FIRMWARE = Path(__file__).resolve().parent.parent / "firmware"
HARNESS = FIRMWARE / "build" / "hx711-sim"
SIGNAL = "ramp:-8389000:8404280:6720"  # the whole 24-bit range and past it, both saturation codes


def measure(rate: int, samples: int, tmp: Path) -> dict[str, object]:
    """One run of `samples` lines at `rate` per second, read by the driver."""
    link = tmp / f"lc{rate}"
    stats_path = tmp / f"stats{rate}.json"
    argv = [str(HARNESS), "--fast", "--wait-open", "--link", str(link), "--rate", str(rate)]
    argv += ["--signal", SIGNAL, "--stats", str(stats_path)]  # stopped once the driver has them all
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    if not proc.stdout.readline().startswith("PTY "):
        raise SystemExit("hx711-sim did not start")
    received = []
    with SerialLoadCell(str(link), baud=115200, stale_timeout_s=120.0) as driver:
        deadline = time.monotonic() + 600
        while len(received) < samples and time.monotonic() < deadline:
            received += driver.poll()
            time.sleep(0.01)
        lines = driver.line_stats()
    proc.terminate()
    proc.wait(timeout=60)
    received = received[:samples]
    stats = json.loads(stats_path.read_text())
    steps = [(b.device_time_us - a.device_time_us) % 2**32 for a, b in itertools.pairwise(received)]
    return {
        "rate_sps": rate,
        "samples_read_by_driver": len(received),
        "seq_continuous": [s.seq for s in received] == list(range(len(received))),
        "sequence_gaps": lines.sequence_gaps,
        "missing_samples": lines.missing_samples,
        "garbled_lines": lines.garbled_lines + lines.checksum_failures,
        "missed_conversions": stats["missed_conversions"],
        "raw_mismatches": stats["raw_mismatches"],
        "period_us": stats["period_us"],
        "t_us_step_min": min(steps),
        "t_us_step_max": max(steps),
        "t_us_vs_ready_step_max_us": stats["t_us_vs_ready_step_max_us"],
        "latency_us_min": stats["latency_us_min"],
        "latency_us_mean": stats["latency_us_mean"],
        "latency_us_max": stats["latency_us_max"],
        "sim_seconds": stats["sim_seconds"],
        "speed_x_real_time": stats["speed_x_real_time"],
    }


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--rates", default="80,10,320", help="comma-separated: 10, 20, 80, 320")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:  # every rate, 100 samples each (10 simulated seconds at 10/s)
        args.samples = 100
    build = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "all", "sim"], capture_output=True, text=True)
    if build.returncode:
        print(build.stdout + build.stderr, file=sys.stderr)
        return 1
    size = build.stdout.strip().splitlines()[-1]
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (int(r) for r in args.rates.split(",")):
            # At 10/s, 10,000 samples are 1,000 simulated seconds: a tenth of them says the same.
            n = args.samples if rate >= 80 else max(100, args.samples // 10)
            results.append(measure(rate, n, Path(tmp)))
    if args.smoke and not all(r["samples_read_by_driver"] for r in results):
        raise SystemExit(f"smoke: the driver read no sample at some rate: {results}")
    if args.json:
        print(json.dumps({"size": size, "runs": results}, indent=1))
        return 0
    print(size)
    print("rate  samples  seq-ok  gaps  missing  missed  period-us  t-us step min/max  |t-us - ready|  "
          "latency us min/mean/max  sim x real")  # fmt: skip
    for r in results:
        print(
            f"{r['rate_sps']:>4}  {r['samples_read_by_driver']:>7}  {r['seq_continuous']!s:>6}  "
            f"{r['sequence_gaps']:>4}  {r['missing_samples']:>7}  {r['missed_conversions']:>6}  "
            f"{r['period_us']:>9}  {r['t_us_step_min']:>8}/{r['t_us_step_max']:<8}  "
            f"{r['t_us_vs_ready_step_max_us']:>14}  "
            f"{r['latency_us_min']:>7.0f}/{r['latency_us_mean']:.0f}/{r['latency_us_max']:<7.0f}  "
            f"{r['speed_x_real_time']:>10.1f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
