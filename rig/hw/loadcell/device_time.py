"""Mapping a device's sample clock onto the host clock, so samples carry their sampling time.

A load cell that sends its own microsecond clock (`rig-lc1`) lets the host time each sample when
it was taken rather than when its line happened to be read (several lines often arrive in one
read). The mapping is the classic minimum-latency estimate: every line arrives after it was
sampled, so `offset = min(receipt − device time)` over the lines seen is the best estimate of the
clocks' offset; a small leak per sample lets it follow drift between the two clocks. A mapped
time is never later than the line's receipt.
"""

from __future__ import annotations

from collections.abc import Sequence

DEVICE_CLOCK_WRAP_US = 1 << 32
# How fast the offset estimate may move later, per sample: 2 µs at 1 kHz follows a drift of up to
# 2000 ppm, far beyond a crystal's, while keeping the estimate near the minimum latency.
OFFSET_LEAK_NS = 2_000


class DeviceClockMapper:
    """Maps wrapping 32-bit device microseconds onto host epoch nanoseconds."""

    def __init__(self) -> None:
        self._offset_ns: int | None = None
        self._last_raw_us: int | None = None
        self._wraps = 0

    def reset(self) -> None:
        """Forget the mapping (e.g. after reopening the port: the device may have restarted)."""
        self.__init__()  # type: ignore[misc]

    def sample_time_ns(self, device_time_us: int | None, receipt_ns: int) -> int:
        """The host time at which a sample stamped `device_time_us` was taken."""
        if device_time_us is None:
            return receipt_ns
        last = self._last_raw_us
        if last is not None and device_time_us < last and last - device_time_us > DEVICE_CLOCK_WRAP_US // 2:
            self._wraps += 1
        self._last_raw_us = device_time_us
        device_ns = (device_time_us + self._wraps * DEVICE_CLOCK_WRAP_US) * 1000
        observed = receipt_ns - device_ns
        offset = self._offset_ns
        offset = observed if offset is None else min(offset + OFFSET_LEAK_NS, observed)
        self._offset_ns = offset
        return offset + device_ns

    def sample_times_ns(self, device_times_us: Sequence[int | None], receipt_ns: int) -> list[int]:
        """`sample_time_ns` of each device time in turn (all received at `receipt_ns`), in one call."""
        if not device_times_us or device_times_us[0] is None:  # a format without a device clock
            return [self.sample_time_ns(t, receipt_ns) for t in device_times_us]
        # The same steps as `sample_time_ns`, with the state in locals for the whole batch.
        offset, last, wraps = self._offset_ns, self._last_raw_us, self._wraps
        half_wrap = DEVICE_CLOCK_WRAP_US // 2
        unwrap_us = wraps * DEVICE_CLOCK_WRAP_US
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
            observed = receipt_ns - device_ns
            if offset is None:
                offset = observed
            else:  # min(offset + OFFSET_LEAK_NS, observed) without a call
                offset += OFFSET_LEAK_NS
                if observed < offset:
                    offset = observed
            append(offset + device_ns)
        self._offset_ns, self._last_raw_us, self._wraps = offset, last, wraps
        return times
