"""Servo discovery: `scan_port` broadcast-pings a port at each baud rate and lists who answered.

What this module owns: `scan_port` and `ScannedServo`. It opens its own port handler (no handshake,
no configured servos), so it works before a rig config exists; model names come from
`control_table.model_name_for`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import serial
from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler, PortHandler

from rig.errors import CommunicationError, InputError, NotConnectedError
from rig.hw.dxl import control_table as ct
from rig.hw.dxl.errors import comm_result_name


@dataclass(frozen=True, slots=True)
class ScannedServo:
    """A servo found by `scan_port`."""

    servo_id: int
    model_number: int
    model: str  # model name, or "unknown (N)"
    firmware: int
    baud: int


def scan_port(
    port_name: str, bauds: Sequence[int], *, port_factory: Callable[[str], PortHandler] = PortHandler
) -> list[ScannedServo]:
    """Broadcast-ping the bus at each baud rate; the servos that answered, sorted by baud then ID.

    The SDK waits its whole broadcast window whatever answers (about 0.8 s at 1 Mbps and 1.4 s at
    57600), so a scan takes about that long per baud rate. Ping status packets carry the firmware
    version, so no further read is needed.

    Raises:
        InputError: a baud rate the SDK cannot set.
        NotConnectedError: the port cannot be opened.
        CommunicationError: the replies were garbled beyond use.
    """
    for baud in bauds:
        if baud not in ct.SDK_BAUDS:
            raise InputError(f"--baud {baud} cannot be set by dynamixel-sdk; allowed: {ct.SDK_BAUDS}")
    ph = PacketHandler(2.0)
    found: list[ScannedServo] = []
    port: PortHandler | None = None
    try:
        try:
            port = port_factory(port_name)
            if not port.openPort():
                raise NotConnectedError(f"cannot open servo port {port_name}")
        except (OSError, serial.SerialException, ValueError) as exc:
            raise NotConnectedError(f"cannot open servo port {port_name}: {exc}") from exc
        for baud in bauds:
            try:
                if not port.setBaudRate(baud):
                    raise NotConnectedError(f"cannot set {port_name} to {baud} baud")
                port.is_using = False
                answers, result = ph.broadcastPing(port)
            except (OSError, serial.SerialException) as exc:
                raise NotConnectedError(f"servo port {port_name} failed: {exc}") from exc
            except (IndexError, ValueError, TypeError, KeyError) as exc:
                raise CommunicationError(
                    f"broadcast ping on {port_name} at {baud} baud: "
                    f"malformed reply ({type(exc).__name__}: {exc})"
                ) from exc
            if result not in (COMM_SUCCESS, COMM_RX_TIMEOUT) and not answers:
                raise CommunicationError(
                    f"broadcast ping on {port_name} at {baud} baud failed: {comm_result_name(result)}"
                )
            for servo_id, (model_number, firmware) in sorted(answers.items()):
                found.append(
                    ScannedServo(servo_id, model_number, ct.model_name_for(model_number), firmware, baud)
                )
    finally:
        if port is not None and port.is_open:
            with contextlib.suppress(Exception):
                port.closePort()
    return found


__all__ = ["ScannedServo", "scan_port"]
