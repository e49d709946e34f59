"""Packet round trips on one Dynamixel port over dynamixel-sdk: retries, reply checks, counters.

What this module owns: the SDK's PortHandler/PacketHandler of one port, one exchange at a time,
the checks on every reply, counted retries and `BusStats`. It deals in IDs, addresses and bytes;
field names, SI units, the Alert bit and limits belong to `rig.hw.dxl.bus`.

* **One owner, not thread-safe.** dynamixel-sdk has no locking beyond `port.is_using`; one thread
  must own the port. A re-entrant call (e.g. from a signal handler in the middle of a transaction)
  raises `BusOwnershipError` instead of corrupting the exchange.
* **Every SDK call is wrapped.** The SDK can raise `IndexError` on short, late or param-less status
  packets and matches replies to requests by ID only. Each exchange checks the result code, the
  ERR byte's error number and the parameter length, turns anything wrong into a retryable failure,
  and after `retries` extra tries raises `RigTimeoutError` (nothing answered) or
  `CommunicationError` (garbled), both saying "after N tries". A servo that refuses an instruction
  (non-zero error number other than CRC) raises `InstructionRejected` at once. Before a retry the
  transport waits `retry_settle_s` and clears the input buffer so a late reply cannot be taken for
  the next answer.
"""

from __future__ import annotations

import contextlib
import termios
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any, TypeVar

import serial
from dynamixel_sdk import (
    BROADCAST_ID,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    INST_PING,
    INST_READ,
    INST_WRITE,
    PacketHandler,
    PortHandler,
)

from rig.errors import CommunicationError, NotConnectedError, RigError, RigTimeoutError
from rig.hw.dxl.error_codes import (
    ERRNUM_CRC,
    ERROR_NUMBER_MASK,
    InstructionRejected,
    comm_result_name,
    error_number_name,
    servo_label,
)
from rig.hw.seams import Clock

T = TypeVar("T")


def port_vanished(port_name: str, exc: BaseException) -> str:
    """The message for a servo port that failed under an open connection (the adapter gone)."""
    detail = exc.args[1] if isinstance(exc, termios.error) and len(exc.args) > 1 else str(exc)
    return (
        f"servo port {port_name} vanished ({detail}): the servo adapter (e.g. a U2D2) was unplugged or lost "
        "power; plug it back in, check that it is listed in /dev/serial/by-id/, and resume the run "
        "(`rig run --resume RUN_ID`, with `--out DIR` if its logs are not in logs/)"
    )


class BusOwnershipError(RigError, RuntimeError):
    """The bus was used re-entrantly (it has exactly one owner and is not thread-safe)."""


@dataclass(slots=True)
class BusStats:
    """Counters of what happened on the bus since the driver was made (a run).

    The transport counts exchanges; the bus adds alerts, reboots and replies it rejects.
    """

    operations: int = 0  # logical exchanges asked for (a sync read is one)
    attempts: int = 0  # SDK exchanges made, retries included
    retries: int = 0  # attempts beyond the first
    timeouts: int = 0  # attempts that got no status packet
    corrupt: int = 0  # attempts with a garbled, short or mismatched reply
    recovered: int = 0  # operations that succeeded after at least one retry
    failures: int = 0  # operations that gave up after every try
    alerts: int = 0  # status packets carrying the Alert bit
    reboots: int = 0  # reboots started
    fast_sync_reads: int = 0
    sync_reads: int = 0
    sync_writes: int = 0
    watchdog_trips: int = 0  # Bus Watchdog trips found (register 98 read -1) and cleared

    def since(self, earlier: BusStats) -> BusStats:
        """The counts after `earlier` (e.g. one trial's); all of these if the driver was made since."""
        pairs = [(getattr(self, f.name), getattr(earlier, f.name)) for f in fields(self)]
        if any(now < then for now, then in pairs):
            return replace(self)
        return BusStats(*(now - then for now, then in pairs))

    @property
    def clean(self) -> bool:
        """No retry, timeout, corrupt reply, failed operation, reboot or Bus Watchdog trip."""
        lost = (self.retries, self.timeouts, self.corrupt, self.failures)
        return not any(lost) and not self.reboots and not self.watchdog_trips

    def describe(self) -> str:
        """One line for an operator."""
        return (
            f"{self.operations} operations; {self.retries} retries, {self.timeouts} timeouts, "
            f"{self.corrupt} corrupt replies, {self.failures} failures, {self.reboots} reboots"
            + (f", {self.watchdog_trips} Bus Watchdog trips" if self.watchdog_trips else "")
        )


class _AttemptFailed(Exception):
    """One SDK exchange failed in a way a retry may fix."""

    def __init__(self, detail: str, timeout: bool) -> None:
        super().__init__(detail)
        self.detail = detail
        self.timeout = timeout


class Transport:
    """Exchanges with the servos on one serial port, each with up to `retries` counted retries.

    Args:
        port_name: serial device (or a pty link / emulator name in simulation).
        clock: used to wait before a retry.
        roles: role of each configured servo, for messages ("servo 2 (winch)").
        retries: extra tries after a failed exchange (0 = try once).
        retry_settle_s: quiet time before a retry.
        port_factory: builds the SDK port handler from the port name.
    """

    def __init__(
        self,
        port_name: str,
        clock: Clock,
        roles: Mapping[int, str],
        *,
        retries: int,
        retry_settle_s: float,
        port_factory: Callable[[str], PortHandler],
    ) -> None:
        self.port_name = port_name
        self.retries = retries
        self.stats = BusStats()
        self._clock = clock
        self._roles = dict(roles)
        self._retry_settle_s = retry_settle_s
        self._port_factory = port_factory
        self._ph = PacketHandler(2.0)
        self._port: PortHandler | None = None
        self._busy = False
        # Said with every timeout when set: e.g. the port's slow USB latency timer (set by the bus).
        self.timeout_cause = ""

    # ------------------------------------------------------------------ the port

    @property
    def has_port(self) -> bool:
        """True from `open` until `close_quietly`."""
        return self._port is not None

    def open(self, baud: int) -> None:
        """Open the port at `baud`; on failure close it again and raise `NotConnectedError`."""
        try:
            port = self._port_factory(self.port_name)
            self._port = port
            opened = port.openPort() and port.setBaudRate(baud)
        except (OSError, serial.SerialException, ValueError) as exc:
            self.close_quietly()
            raise NotConnectedError(f"cannot open servo port {self.port_name}: {exc}") from exc
        if not opened:
            self.close_quietly()
            raise NotConnectedError(f"cannot open servo port {self.port_name} at {baud} baud")

    def close_quietly(self, errors: list[BaseException] | None = None) -> None:
        """Close the port if open; a failure is appended to `errors` (when given), never raised."""
        port, self._port = self._port, None
        if port is None:
            return
        try:
            if port.is_open:
                port.closePort()
        except Exception as exc:
            if errors is not None:
                errors.append(NotConnectedError(f"closing servo port {self.port_name} failed: {exc}"))

    def abandon_transaction(self) -> None:
        """Forget a transaction cut short by an exception, so shutdown can still use the port."""
        self._busy = False

    # ------------------------------------------------------------------ exchanges

    def ping(self, servo_id: int) -> int:
        """Ping one servo (with retries); its model number."""

        def attempt() -> int:
            _, data = self._unicast(servo_id, INST_PING, (), 3)
            return data[0] | (data[1] << 8)

        return self._run(f"ping of servo {servo_id}", attempt)

    def read(self, servo_id: int, address: int, size: int, signed: bool, what: str) -> tuple[int, int]:
        """Read `size` bytes at `address` (with retries); (value, ERR byte).

        A refusal (non-zero error number) is returned as value 0 with its ERR byte, for the caller
        to check the Alert bit before reporting it.
        """
        params = (address & 0xFF, address >> 8, size & 0xFF, size >> 8)

        def attempt() -> tuple[int, int]:
            err, data = self._unicast(servo_id, INST_READ, params, size)
            if err & ERROR_NUMBER_MASK:
                return 0, err  # reported after the alert check
            return int.from_bytes(data, "little", signed=signed), err

        return self._run(what, attempt)

    def write(self, servo_id: int, address: int, data: Sequence[int], what: str) -> int:
        """Write `data` at `address` and wait for the status (with retries); the ERR byte."""
        params = [address & 0xFF, address >> 8, *data]

        def attempt() -> int:
            err, _ = self._unicast(servo_id, INST_WRITE, params, 0)
            return err

        return self._run(what, attempt)

    def sync_read(
        self, start: int, length: int, ids: list[int], *, fast: bool, what: str
    ) -> dict[int, tuple[int, bytes]]:
        """One (Fast) Sync Read of `length` bytes at `start` from `ids`; (ERR byte, data) per ID."""
        if fast:
            out = self._run(
                f"fast sync read of {what}", lambda: self._fast_sync_read_once(start, length, ids)
            )
            self.stats.fast_sync_reads += 1
        else:
            out = self._run(f"sync read of {what}", lambda: self._sync_read_once(start, length, ids))
            self.stats.sync_reads += 1
        return out

    def sync_write(self, address: int, size: int, param: list[int], what: str) -> None:
        """Broadcast a Sync Write (no reply); `param` is ID then `size` data bytes per servo."""

        def attempt() -> None:
            result = self._sdk(self._ph.syncWriteTxOnly, self._port, address, size, param, len(param))
            if result != COMM_SUCCESS:
                raise _AttemptFailed(f"sync write not sent: {comm_result_name(result)}", timeout=False)

        self._run(f"sync write of {what}", attempt)
        self.stats.sync_writes += 1

    def unanswered(self, servo_ids: Iterable[int]) -> list[int]:
        """Ping each servo once (no retry); the ones that did not answer at all."""
        silent = []
        for servo_id in servo_ids:
            self.stats.attempts += 1
            try:
                with self._transaction():
                    _, result, _ = self._sdk_unchecked(self._ph.ping, self._port, servo_id)
            except CommunicationError:
                continue
            if result == COMM_RX_TIMEOUT:
                silent.append(servo_id)
        return silent

    def ping_once(self, servo_id: int) -> int:
        """One ping, no retry: the SDK result code (`COMM_SUCCESS` if it answered), -1 if garbled."""
        try:
            with self._transaction():
                self.stats.attempts += 1
                _, result, _ = self._sdk_unchecked(self._ph.ping, self._port, servo_id)
        except CommunicationError:
            result = -1
        return int(result)

    def send_reboot(self, servo_id: int) -> None:
        """Send Reboot once, no retry; `InstructionRejected` if the servo refused it.

        No retry: if the reply was lost the servo may already be booting, and it ignores
        instructions while it boots. The caller polls with `ping_once` either way.
        """
        self.stats.operations += 1
        self.stats.attempts += 1
        with self._transaction():
            result, err = self._sdk_unchecked(self._ph.reboot, self._port, servo_id)
        if result == COMM_SUCCESS and err & ERROR_NUMBER_MASK:
            raise InstructionRejected(
                f"{self._label(servo_id)} refused the reboot: {error_number_name(err)}", servo_id, err
            )

    # ------------------------------------------------------------------ machinery

    def _label(self, servo_id: int) -> str:
        return servo_label(servo_id, self._roles.get(servo_id))

    @contextlib.contextmanager
    def _transaction(self) -> Iterator[None]:
        if self._busy:
            raise BusOwnershipError(
                f"servo bus on {self.port_name} used re-entrantly: it has one owner and is not thread-safe"
            )
        if self._port is None:
            raise NotConnectedError(f"servo port {self.port_name} is closed")
        self._busy = True
        self._port.is_using = False  # we are the only user; a stale flag comes from an interrupted call
        try:
            yield
        finally:
            self._busy = False

    def _sdk(self, fn: Callable[..., T], *args: Any) -> T:
        """Call the SDK; its stray exceptions become a retryable failure or `NotConnectedError`.

        A port that fails under the SDK (EIO when a USB adapter is pulled out; pyserial raises it as
        `SerialException`, `OSError` or, from its buffer flush, `termios.error`) is reported as the
        port that vanished, with what to do.
        """
        try:
            return fn(*args)
        except (serial.SerialException, OSError, termios.error) as exc:
            raise NotConnectedError(port_vanished(self.port_name, exc)) from exc
        except (IndexError, ValueError, TypeError, KeyError) as exc:
            if self._port is not None:
                self._port.is_using = False
            raise _AttemptFailed(
                f"malformed reply (SDK raised {type(exc).__name__}: {exc})", timeout=False
            ) from exc

    def _sdk_unchecked(self, fn: Callable[..., T], *args: Any) -> T:
        try:
            return self._sdk(fn, *args)
        except _AttemptFailed as exc:
            raise CommunicationError(f"servo bus on {self.port_name}: {exc.detail}") from exc

    def _settle(self) -> None:
        self._clock.sleep(self._retry_settle_s)
        port = self._port
        if port is not None:
            with contextlib.suppress(Exception):
                port.clearPort()

    def _run(self, what: str, attempt: Callable[[], T]) -> T:
        """One logical exchange with up to `retries` counted retries; typed error when all fail."""
        stats = self.stats
        stats.operations += 1
        tries = 1 + self.retries
        last: _AttemptFailed | None = None
        all_timeouts = True
        with self._transaction():
            for n in range(tries):
                if n:
                    stats.retries += 1
                    self._settle()
                stats.attempts += 1
                try:
                    value = attempt()
                except InstructionRejected:
                    stats.failures += 1
                    raise
                except _AttemptFailed as failure:
                    last = failure
                    if failure.timeout:
                        stats.timeouts += 1
                    else:
                        stats.corrupt += 1
                        all_timeouts = False
                    continue
                if n:
                    stats.recovered += 1
                return value
        stats.failures += 1
        assert last is not None
        message = (
            f"{what} on {self.port_name} failed after {tries} tr{'y' if tries == 1 else 'ies'}: {last.detail}"
        )
        if all_timeouts:
            raise RigTimeoutError(message + (f" ({self.timeout_cause})" if self.timeout_cause else ""))
        raise CommunicationError(message)

    def _check_error_number(self, servo_id: int, err: int) -> None:
        number = err & ERROR_NUMBER_MASK
        if number == 0:
            return
        label = self._label(servo_id)
        if number == ERRNUM_CRC:  # our instruction was garbled on the way: worth a retry
            raise _AttemptFailed(f"{label} reported a CRC error in the instruction", timeout=False)
        raise InstructionRejected(
            f"{label} rejected the instruction: {error_number_name(err)}", servo_id, number
        )

    def _retry_on_crc_error(self, servo_id: int, err: int) -> None:
        if err & ERROR_NUMBER_MASK == ERRNUM_CRC:  # the instruction was garbled on the way
            raise _AttemptFailed(
                f"{self._label(servo_id)} reported a CRC error in the instruction", timeout=False
            )

    def _unicast(
        self, servo_id: int, instruction: int, params: Sequence[int], reply_params: int
    ) -> tuple[int, bytes]:
        """One instruction to one servo and its status: (ERR byte, params).

        Built on the SDK's `txRxPacket`, which matches a reply by ID only; the reply's LEN is
        checked here against what this instruction's status must carry, so a late status meant
        for an earlier instruction (e.g. a param-less write status arriving during a 1-byte read,
        which the SDK's `read1ByteTxRx` would return its CRC byte for) is caught and retried.
        A refusal (non-zero error number) may carry no params and is returned as is.
        """
        packet = [0] * (10 + len(params))
        packet[4] = servo_id
        packet[5] = (len(params) + 3) & 0xFF
        packet[6] = (len(params) + 3) >> 8
        packet[7] = instruction
        packet[8 : 8 + len(params)] = params
        reply, result, err = self._sdk(self._ph.txRxPacket, self._port, packet)
        if result != COMM_SUCCESS:
            raise _AttemptFailed(comm_result_name(result), timeout=result == COMM_RX_TIMEOUT)
        self._retry_on_crc_error(servo_id, err)
        length = reply[5] | (reply[6] << 8)
        if err & ERROR_NUMBER_MASK and length == 4:
            return err, b""
        if length != reply_params + 4:
            raise _AttemptFailed(
                f"status with {length - 4} params where {reply_params} were due (a late reply?)",
                timeout=False,
            )
        return err, bytes(reply[9 : 9 + reply_params])

    def _sync_read_once(self, start: int, length: int, ids: list[int]) -> dict[int, tuple[int, bytes]]:
        port, ph = self._port, self._ph
        result = self._sdk(ph.syncReadTx, port, start, length, ids, len(ids), False)
        if result != COMM_SUCCESS:
            raise _AttemptFailed(f"sync read not sent: {comm_result_name(result)}", timeout=False)
        out: dict[int, tuple[int, bytes]] = {}
        for servo_id in ids:
            data, result, err = self._sdk(ph.readRx, port, servo_id, length)
            if result != COMM_SUCCESS:
                raise _AttemptFailed(
                    f"{self._label(servo_id)}: {comm_result_name(result)}",
                    timeout=result == COMM_RX_TIMEOUT,
                )
            self._check_error_number(servo_id, err)
            if len(data) != length:
                raise _AttemptFailed(
                    f"{self._label(servo_id)}: {len(data)} data bytes, expected {length}",
                    timeout=False,
                )
            out[servo_id] = (err, bytes(data))
        return out

    def _fast_sync_read_once(self, start: int, length: int, ids: list[int]) -> dict[int, tuple[int, bytes]]:
        port, ph = self._port, self._ph
        result = self._sdk(ph.syncReadTx, port, start, length, ids, len(ids), True)
        if result != COMM_SUCCESS:
            raise _AttemptFailed(f"fast sync read not sent: {comm_result_name(result)}", timeout=False)
        packet, result = self._sdk(ph.rxPacket, port, True)
        if result != COMM_SUCCESS:
            raise _AttemptFailed(comm_result_name(result), timeout=result == COMM_RX_TIMEOUT)
        stride = length + 4  # ERR, ID, data, CRC
        expected = 8 + stride * len(ids)
        if packet[4] != BROADCAST_ID or len(packet) != expected:
            raise _AttemptFailed(
                f"fast sync read reply of {len(packet)} bytes from id {packet[4]}, "
                f"expected {expected} from 0xFE",
                timeout=False,
            )
        raw = bytes(packet)
        out: dict[int, tuple[int, bytes]] = {}
        index = 8
        for servo_id in ids:
            err, found = raw[index], raw[index + 1]
            if found != servo_id:
                raise _AttemptFailed(
                    f"fast sync read entry from id {found} where {servo_id} was due", timeout=False
                )
            self._check_error_number(servo_id, err)
            out[servo_id] = (err, raw[index + 2 : index + 2 + length])
            index += stride
        return out


__all__ = ["BusOwnershipError", "BusStats", "Transport"]
