"""Setting one servo's ID and baud rate: find the only servo on the bus at any baud, write, verify.

What this module owns: `find_single_servo` and `assign_id_and_baud`, the hardware half of
`rig setup-servos`, which connects one servo at a time (a new servo is ID 1 at 57600 baud, so
several on one bus would answer as one). Protocol 2.0 only; a servo on Protocol 1.0 is not found
here (`rig scan` names it and how to switch it). ID (7) and Baud Rate (8) are EEPROM: torque goes
off first. The ID is written first, at the old baud (the servo answers that write under its old
ID), then the baud rate under the new ID (answered at the old rate); the servo is then pinged at
the new rate under the new ID, and both registers are read back.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

import serial
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from rig.errors import CommunicationError, NotConnectedError
from rig.hw.dxl import control_table as ct
from rig.hw.dxl.discovery import ScannedServo, scan_port
from rig.hw.dxl.error_codes import comm_result_name, error_number_name

# The order the bauds are tried in: the target first, then a new servo's 57600, then the rest.
FACTORY_BAUD = 57_600


@dataclass(frozen=True, slots=True)
class ServoSetup:
    """What `assign_id_and_baud` did: from where to where, verified by reading both back."""

    model: str
    old_id: int
    old_baud: int
    new_id: int
    new_baud: int


# The X-series baud rates (Baud Rate(8)) that dynamixel-sdk can set on a port: where a servo may be.
SETTABLE_BAUDS = tuple(b for b in ct.BAUD_RATES.values() if b in ct.SDK_BAUDS)


def search_order(target_baud: int) -> list[int]:
    """Every X-series baud rate the SDK can set, the target and the factory default first."""
    bauds = list(SETTABLE_BAUDS)
    first = [target_baud, FACTORY_BAUD]
    return list(dict.fromkeys([*(b for b in first if b in bauds), *bauds]))


def find_single_servo(
    port_name: str, bauds: Sequence[int], *, port_factory: Callable[[str], PortHandler] = PortHandler
) -> list[ScannedServo]:
    """The servos answering at the first baud rate where any answer (one is what setup wants)."""
    for baud in bauds:
        found = scan_port(port_name, [baud], port_factory=port_factory)
        if found:
            return found
    return []


@contextlib.contextmanager
def _port(port_name: str, baud: int, factory: Callable[[str], PortHandler]) -> Iterator[PortHandler]:
    try:
        port = factory(port_name)
        if not (port.openPort() and port.setBaudRate(baud)):
            raise NotConnectedError(f"cannot open servo port {port_name} at {baud} baud")
    except (OSError, serial.SerialException, ValueError) as exc:
        raise NotConnectedError(f"cannot open servo port {port_name}: {exc}") from exc
    try:
        yield port
    finally:
        with contextlib.suppress(Exception):
            port.closePort()


def _write1(ph: PacketHandler, port: PortHandler, servo_id: int, address: int, value: int, what: str) -> None:
    result, err = ph.write1ByteTxRx(port, servo_id, address, value)
    if result != COMM_SUCCESS or err & 0x7F:
        problem = comm_result_name(result) if result != COMM_SUCCESS else error_number_name(err)
        raise CommunicationError(f"servo {servo_id}: the write of {what} failed ({problem})")


def _read1(ph: PacketHandler, port: PortHandler, servo_id: int, address: int, what: str) -> int:
    value, result, err = ph.read1ByteTxRx(port, servo_id, address)
    if result != COMM_SUCCESS or err & 0x7F:
        problem = comm_result_name(result) if result != COMM_SUCCESS else error_number_name(err)
        raise CommunicationError(f"servo {servo_id}: the read of {what} failed ({problem})")
    return int(value)


def assign_id_and_baud(
    port_name: str,
    found: ScannedServo,
    new_id: int,
    new_baud: int,
    *,
    port_factory: Callable[[str], PortHandler] = PortHandler,
) -> ServoSetup:
    """Torque off, write ID then Baud Rate, and verify at the new rate; `CommunicationError` if not."""
    ph = PacketHandler(2.0)
    with _port(port_name, found.baud, port_factory) as port:
        _write1(ph, port, found.servo_id, ct.ADDR_TORQUE_ENABLE, 0, "Torque Enable = 0")
        if new_id != found.servo_id:
            _write1(ph, port, found.servo_id, ct.ADDR_ID, new_id, f"ID = {new_id}")
        if new_baud != found.baud:
            register = ct.BAUD_REGISTER_BY_RATE[new_baud]
            _write1(ph, port, new_id, ct.ADDR_BAUD_RATE, register, f"Baud Rate = {register} ({new_baud})")
    with _port(port_name, new_baud, port_factory) as port:
        model_number, result, _ = ph.ping(port, new_id)
        if result != COMM_SUCCESS:
            raise CommunicationError(
                f"after the writes, no servo {new_id} answers at {new_baud} baud ({comm_result_name(result)})"
            )
        read_id = _read1(ph, port, new_id, ct.ADDR_ID, "ID")
        read_baud = ct.BAUD_RATES.get(_read1(ph, port, new_id, ct.ADDR_BAUD_RATE, "Baud Rate"))
        if model_number != found.model_number or read_id != new_id or read_baud != new_baud:
            raise CommunicationError(
                f"servo {new_id} reads back id {read_id}, baud {read_baud}, model {model_number}; "
                f"expected id {new_id}, baud {new_baud}, model {found.model_number}"
            )
    return ServoSetup(found.model, found.servo_id, found.baud, new_id, new_baud)


def describe_found(found: Iterable[ScannedServo]) -> str:
    """'id 1 (XM430-W350) at 57600 baud, ...' for messages."""
    return ", ".join(f"id {s.servo_id} ({s.model}) at {s.baud} baud" for s in found)


__all__ = ["ServoSetup", "assign_id_and_baud", "describe_found", "find_single_servo", "search_order"]
