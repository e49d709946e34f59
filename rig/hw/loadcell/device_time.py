"""Mapping a device's sample clock onto the host clock, so samples carry their sampling time.

A load cell that sends its own microsecond clock (`rig-lc1`) lets the host time each sample when
it was taken rather than when its line happened to be read (several lines often arrive in one
read). The mapping has two parts, both estimated from the lower envelope of
`observed = receipt − device time` (every line arrives after it was sampled, so the smallest
observed values are the ones with the least transmission and reading delay):

* **Offset**: the classic minimum-latency estimate, `offset = min(observed)`, with a small leak
  per sample (`OFFSET_LEAK_NS`) so that it can also move up.
* **Rate** (`track_rate`, on by default): a device clock that runs a fraction `s` slow or fast
  makes `observed` climb or fall by `s` per device second. A leak of 2 µs per sample follows at
  most 2 µs per sample period (2000 ppm at 1 kHz but only 20 ppm at 10/s), so a resonator 0.5 %
  off would leave the stamps seconds wrong after minutes. The mapper therefore takes the minimum
  of `observed` in each window of device time (`RATE_WINDOW_S`, or `RATE_WINDOW_SAMPLES` samples
  if that is longer), and estimates `s` as the slope between the first window's minimum and the
  latest window's minimum: a two-point fit of the lower envelope, whose error is the minima's
  jitter divided by the time between them, so it improves the longer the device runs. The device
  time is then corrected, `d' = d + s (d − d_first)`, the offset is re-anchored on the first
  minimum in the corrected frame, and the offset estimate above runs on `d'`.
  A slope below `RATE_DEADBAND_PPM` is not applied until one above it has been (a crystal's
  tolerance is tens of ppm, which the leak follows at every rate from 10/s): so a device whose
  clock keeps the host's time is mapped exactly as by the offset alone.

A mapped time is never later than the line's receipt once the rate is known (before that, the
first line of a read is placed at its receipt). `benchmarks/bench_device_clock.py` measures the
stamps' error after an hour with a clock 1 % off, with and without rate tracking.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

DEVICE_CLOCK_WRAP_US = 1 << 32
# How fast the offset estimate may move later, per sample: 2 µs at 1 kHz follows a drift of up to
# 2000 ppm, far beyond a crystal's, while keeping the estimate near the minimum latency.
OFFSET_LEAK_NS = 2_000
# The rate estimate: minima of `observed` per window of device time, at least this long ...
RATE_WINDOW_S = 5.0
# ... and holding at least this many samples (50 s at 10/s: enough lines for a clean minimum).
RATE_WINDOW_SAMPLES = 500
# A slope is first applied once it exceeds this (thereafter every estimate is applied).
RATE_DEADBAND_PPM = 10.0


class DeviceClockMapper:
    """Maps wrapping 32-bit device microseconds onto host epoch nanoseconds (offset and rate)."""

    def __init__(self, track_rate: bool = True) -> None:
        self.track_rate = track_rate
        self._offset_ns: int | None = None
        self._last_raw_us: int | None = None
        self._wraps = 0
        # Rate tracking: the current window (its start, sample count, minimum and where it was).
        self._window_start_ns: int | None = None
        self._window_samples = 0
        self._window_min: tuple[int, int] | None = None  # (device ns, observed ns)
        self._first_min: tuple[int, int] | None = None
        self._skew = 0.0  # applied fractional rate error of the device clock (observed per device ns)
        self._estimate = 0.0  # latest estimate, applied or not
        self._rate_known = False
        # The last stamp handed out: a new rate estimate re-anchors the offset, which can put the next
        # stamp a few microseconds before the last one; stamps never go back (the detector needs it).
        self._last_stamp_ns: int | None = None

    def reset(self) -> None:
        """Forget the mapping (e.g. after reopening the port: the device may have restarted)."""
        self.__init__(self.track_rate)  # type: ignore[misc]

    @property
    def skew_ppm(self) -> float:
        """The device clock's estimated rate error in ppm (positive: the device clock runs slow)."""
        return self._estimate * 1e6

    @property
    def applied_skew_ppm(self) -> float:
        """The rate correction in use, in ppm (0 until an estimate beyond the deadband)."""
        return self._skew * 1e6

    def sample_time_ns(self, device_time_us: int | None, receipt_ns: int) -> int:
        """The host time at which a sample stamped `device_time_us` was taken."""
        return self.sample_times_ns([device_time_us], receipt_ns)[0]

    def sample_times_ns(self, device_times_us: Sequence[int | None], receipt_ns: int) -> list[int]:
        """The host time of each device time in turn (all received at `receipt_ns`)."""
        if not device_times_us:
            return []
        if device_times_us[0] is None:  # a format without a device clock
            if any(t is not None for t in device_times_us):
                raise TypeError("device times of one batch must all be set or all be None")
            return [receipt_ns] * len(device_times_us)
        offset, last, wraps = self._offset_ns, self._last_raw_us, self._wraps
        half_wrap = DEVICE_CLOCK_WRAP_US // 2
        unwrap_us = wraps * DEVICE_CLOCK_WRAP_US
        skew = self._skew
        ref_ns = self._first_min[0] if self._first_min is not None else 0
        previous = self._last_stamp_ns
        # Stand-ins that make the first sample's cases fall out of the general ones: `min(inf +
        # leak, observed)` is `observed`; no stamp is below -inf.
        offset_ns: float = math.inf if offset is None else offset
        previous_ns: float = -math.inf if previous is None else previous
        track_rate = self.track_rate
        times: list[int] = []
        append = times.append
        for device_time_us in device_times_us:
            if device_time_us is None:
                raise TypeError("device times of one batch must all be set or all be None")
            if last is not None and device_time_us < last and last - device_time_us > half_wrap:
                wraps += 1
                unwrap_us = wraps * DEVICE_CLOCK_WRAP_US
            last = device_time_us
            device_ns = (device_time_us + unwrap_us) * 1000
            if track_rate and self._window_sample(device_ns, receipt_ns - device_ns):
                # A new rate estimate: the offset is re-anchored in the corrected frame.
                skew = self._skew
                assert self._first_min is not None
                ref_ns, offset_ns = self._first_min
            if skew:
                device_ns += round(skew * (device_ns - ref_ns))
            observed = receipt_ns - device_ns
            offset_ns += OFFSET_LEAK_NS  # min(offset + OFFSET_LEAK_NS, observed) without a call
            if observed < offset_ns:
                offset_ns = observed
            stamp = offset_ns + device_ns
            if stamp < previous_ns:
                stamp = previous_ns
            append(stamp)  # type: ignore[arg-type]  # an int: the stand-ins are gone by now
            previous_ns = stamp
        self._offset_ns, self._last_raw_us, self._wraps = int(offset_ns), last, wraps
        self._last_stamp_ns = int(previous_ns)
        return times

    def _window_sample(self, device_ns: int, observed_ns: int) -> bool:
        """Follow the lower envelope; True when the applied rate changed with this sample."""
        start = self._window_start_ns
        if start is None:
            self._window_start_ns, self._window_samples = device_ns, 0
            self._window_min = (device_ns, observed_ns)
            start = device_ns
        changed = False
        if device_ns - start >= RATE_WINDOW_S * 1e9 and self._window_samples >= RATE_WINDOW_SAMPLES:
            changed = self._close_window()
            self._window_start_ns, self._window_samples = device_ns, 0
            self._window_min = (device_ns, observed_ns)
        self._window_samples += 1
        low = self._window_min
        if low is None or observed_ns < low[1]:
            self._window_min = (device_ns, observed_ns)
        return changed

    def _close_window(self) -> bool:
        low = self._window_min
        assert low is not None
        first = self._first_min
        if first is None:
            self._first_min = low
            return False
        span_ns = low[0] - first[0]
        if span_ns <= 0:
            return False
        self._estimate = (low[1] - first[1]) / span_ns
        if not self._rate_known and abs(self._estimate) * 1e6 < RATE_DEADBAND_PPM:
            return False
        self._rate_known = True
        self._skew = self._estimate
        return True
