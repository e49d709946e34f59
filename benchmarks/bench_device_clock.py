"""Stamp error of the device-clock mapping after an hour, with the device clock 1 % fast or slow.

Issue 21's target: stamps within one sample period after 1 h with a ±1 % clock error, at 10/s,
80/s and 1000/s. The device samples at its nominal rate on its own clock; its clock reads
`host time x (1 + error)`. Each line crosses the UART (line bytes x 10 bits / baud) and reaches the
host at the next read of a USB-serial adapter that hands bytes over every `--usb-ms` (FTDI's
default latency timer, 16 ms) with a random phase jitter of up to 1 ms. Both mappings are fed the
same reads: the rate-tracking `DeviceClockMapper` and the same class with `track_rate=False` (the
offset-only mapping it replaced).

The error reported is `stamp - (true sampling time + line transmission time)`: the constant
transmission delay cannot be seen from the host and is removed; what remains is what the mapping
got wrong. Figures: the largest |error| over the last minute of the hour, in ms and in sample
periods.

Command: `.venv/bin/python benchmarks/bench_device_clock.py` (about a minute; `--hours 0.1` for a
quick look).
"""

from __future__ import annotations

import argparse
import random
import time

from smoke_mode import SMOKE_HELP  # benchmarks/ is the script's directory

from rig.hw.loadcell.device_time import DeviceClockMapper
from rig.hw.loadcell.formats import RigLc1Codec

LINE_BYTES = RigLc1Codec.max_line_bytes
CASES = ((10.0, 115_200), (80.0, 115_200), (1000.0, 921_600))


def run_case(
    rate_hz: float, baud: int, error: float, hours: float, usb_ms: float, seed: int
) -> dict[str, float]:
    """Max |stamp error| over the last minute for both mappings, in ns."""
    rng = random.Random(seed)
    line_ns = LINE_BYTES * 10 * 1e9 / baud
    period_ns = 1e9 / rate_hz
    n_samples = int(hours * 3600 * rate_hz)
    last_minute = n_samples - int(60 * rate_hz)
    mappers = {"rate+offset": DeviceClockMapper(), "offset only": DeviceClockMapper(track_rate=False)}
    worst = dict.fromkeys(mappers, 0.0)
    epoch_ns = 1_700_000_000_000_000_000
    usb_ns = usb_ms * 1e6
    next_read_ns = usb_ns
    batch_true: list[float] = []
    batch_dev: list[int] = []
    k = 0
    while k < n_samples or batch_dev:
        # The device's k-th sample, at k periods of its own clock: host time k x period / (1 + error).
        t_true = k * period_ns / (1 + error) if k < n_samples else float("inf")
        if t_true + line_ns <= next_read_ns:
            batch_true.append(t_true)
            batch_dev.append(int(k * period_ns / 1000) % (1 << 32))
            k += 1
            continue
        if batch_dev:
            receipt = epoch_ns + round(next_read_ns)
            for name, mapper in mappers.items():
                stamps = mapper.sample_times_ns(batch_dev, receipt)
                if k >= last_minute:
                    for stamp, truth in zip(stamps, batch_true, strict=True):
                        err = abs(stamp - (epoch_ns + truth + line_ns))
                        worst[name] = max(worst[name], err)
            batch_true, batch_dev = [], []
        next_read_ns += usb_ns + rng.uniform(-1e6, 1e6)
    worst["period"] = period_ns
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--usb-ms", type=float, default=16.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:  # 36 s: past the stamps' first minute, so the last-minute window is not the whole run
        args.hours = 0.01
    print(f"{args.hours:g} h, reads every {args.usb_ms:g} ms ± 1 ms; |stamp error| max over the last minute")
    print("| rate | clock error | offset only | rate+offset | one period |")
    print("|---|---|---|---|---|")
    for rate_hz, baud in CASES:
        for error in (0.01, -0.01):
            started = time.perf_counter()
            worst = run_case(rate_hz, baud, error, args.hours, args.usb_ms, args.seed)
            period = worst["period"]
            cells = [
                f"{worst[name] / 1e6:.3f} ms ({worst[name] / period:.3g} periods)"
                for name in ("offset only", "rate+offset")
            ]
            print(
                f"| {rate_hz:g}/s @ {baud} | {error:+.0%} | {cells[0]} | {cells[1]} | {period / 1e6:g} ms |"
                f"  ({time.perf_counter() - started:.0f} s)",
                flush=True,
            )


if __name__ == "__main__":
    main()
