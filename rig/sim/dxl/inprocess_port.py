"""In-process transport: a `dynamixel_sdk.PortHandler` whose serial port is an emulated bus in virtual time.

`SimPortHandler(bus, clock)` is a drop-in for `PortHandler(port_name)`: `openPort`/`setBaudRate`
install `SimSerial`, a synchronous pyserial stand-in (no threads). `write` feeds the bus; reply
bytes become readable once the virtual clock reaches their due time (request transfer time at the
baud rate, 10 bits per byte, plus Return Delay Time plus reply transfer time). When the SDK polls
and nothing has arrived, `read` advances the virtual clock to the next due reply, or just past the
SDK's own packet deadline if that comes first, so that a silent servo times out in virtual time
(COMM_RX_TIMEOUT after the same ~34 ms window as on hardware, computed instantly). The SDK's time
source (`getCurrentTime`) is the virtual clock.

Like real hardware, a reply the SDK does not wait for (a unicast Action's status) arrives later
and is taken by the SDK as the answer to its next request to that ID; use `action(BROADCAST_ID)`
or let the clock pass the reply before the next request.
"""

from __future__ import annotations

import heapq
import math

from dynamixel_sdk import PortHandler

from rig.sim.dxl.emulated_bus import EmulatedBus, Reply
from rig.sim.virtual_clock import VirtualClock

IDLE_STEP_NS = 10_000  # minimum virtual-time step when the SDK polls with nothing due and no deadline ahead
DEADLINE_MARGIN_NS = 1_000  # step just past the SDK's deadline so its `>` comparison fires


class SimSerial:
    """The pyserial subset the SDK uses (`write`, `read`, `in_waiting`, `reset_input_buffer`, `close`)."""

    def __init__(self, bus: EmulatedBus, clock: VirtualClock, handler: SimPortHandler) -> None:
        self._bus = bus
        self._clock = clock
        self._handler = handler
        self._rx = bytearray()
        self._pending: list[tuple[int, int, bytes]] = []  # heap of (due_ns, seq, bytes)
        self._seq = 0
        self.is_open = True
        self.port = handler.port_name
        self.baudrate = handler.baudrate
        self.timeout = 0
        self.bytes_written = 0
        self.bytes_read = 0

    # --- pyserial API -------------------------------------------------------------------------------
    def write(self, data: bytes | bytearray | list[int]) -> int:
        """Feed the bus; queue its replies by due time. Returns the number of bytes written."""
        payload = bytes(data)
        replies: list[Reply] = self._bus.feed(payload, self._clock.monotonic_ns())
        for reply in replies:
            self._seq += 1
            heapq.heappush(self._pending, (reply.due_ns, self._seq, reply.data))
        self.bytes_written += len(payload)
        return len(payload)

    def read(self, size: int = 1) -> bytes:
        """Up to `size` bytes that have arrived; advances virtual time first when none have."""
        self._release()
        if not self._rx:
            self._wait()
            self._release()
        out = bytes(self._rx[:size])
        del self._rx[:size]
        self.bytes_read += len(out)
        return out

    @property
    def in_waiting(self) -> int:
        """Bytes that have arrived and not been read."""
        self._release()
        return len(self._rx)

    def reset_input_buffer(self) -> None:
        """Discard bytes that have arrived (replies still on the way are not affected)."""
        self._release()
        self._rx.clear()

    def reset_output_buffer(self) -> None:
        """Nothing is ever buffered for output."""

    def flush(self) -> None:
        """Writes are immediate."""

    def close(self) -> None:
        """Mark closed."""
        self.is_open = False

    # --- virtual time ------------------------------------------------------------------------------
    def _release(self) -> None:
        now = self._clock.monotonic_ns()
        pending = self._pending
        while pending and pending[0][0] <= now:
            self._rx += heapq.heappop(pending)[2]

    def _wait(self) -> None:
        """Advance the clock to the next reply, or just past the SDK's deadline if that is sooner."""
        now = self._clock.monotonic_ns()
        h = self._handler
        deadline_ns = math.ceil((h.packet_start_time + h.packet_timeout) * 1e6) + DEADLINE_MARGIN_NS
        next_due = self._pending[0][0] if self._pending else None
        if deadline_ns > now:
            target = deadline_ns if next_due is None else min(next_due, deadline_ns)
        else:
            # The SDK's window is over and it gives up at its next check; just keep time moving.
            target = now + IDLE_STEP_NS
        self._clock.advance_to_ns(target)


class SimPortHandler(PortHandler):  # type: ignore[misc]  # dynamixel-sdk has no type information
    """A `PortHandler` on an `EmulatedBus` in virtual time (construct as `SimPortHandler(bus, clock)`)."""

    def __init__(self, bus: EmulatedBus, clock: VirtualClock, port_name: str = "sim://dxl") -> None:
        super().__init__(port_name)
        self.bus = bus
        self.clock = clock

    def setupPort(self, cflag_baud: int) -> bool:
        """Install the emulated serial port at `self.baudrate`; the bus line runs at that rate."""
        if self.is_open:  # type: ignore[has-type]  # set by the untyped PortHandler
            self.closePort()
        self.ser = SimSerial(self.bus, self.clock, self)
        self.bus.baud = self.baudrate
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def getCurrentTime(self) -> float:
        """Virtual milliseconds, as the SDK's timeouts expect."""
        return self.clock.monotonic_ns() / 1e6
