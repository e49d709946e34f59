"""Servo discovery: `scan_port` broadcast-pings a port at each baud rate and lists who answered.

What this module owns: `scan_port` and `ScannedServo`. It opens its own port handler (no handshake,
no configured servos), so it works before a rig config exists; model names come from
`control_table.model_name_for`.

Protocol 1.0 servos do not answer a Protocol 2.0 ping, and Protocol 1.0 has no broadcast ping
that answers: given `protocol1_ids`, the scan also pings each of those IDs with Protocol 1.0 at
each baud rate (about 35 ms per silent ID) and names what answers, with how to switch it to
Protocol 2.0 (`protocol1_advice`): an X-series servo by its Protocol Type register, an MX by its
Protocol 2.0 firmware; AX and the like have none.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import serial
from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler, PortHandler

from rig.errors import CommunicationError, InputError, NotConnectedError
from rig.hw.dxl import control_table as ct
from rig.hw.dxl.error_codes import comm_result_name
from rig.inputs.servo_ratings import MX_PROTOCOL_2_NAMES, PROTOCOL_1_MODELS

WIZARD = "DYNAMIXEL Wizard 2.0 (ROBOTIS)"
ADDR_PROTOCOL_1_FIRMWARE = 2  # Firmware Version in the AX/MX Protocol 1.0 tables


@dataclass(frozen=True, slots=True)
class ScannedServo:
    """A servo found by `scan_port`."""

    servo_id: int
    model_number: int
    model: str  # model name, or "unknown (N)"
    firmware: int
    baud: int
    protocol: float = 2.0  # the protocol it answered: 2.0, or 1.0

    @property
    def switch_advice(self) -> str:
        """How to switch it to Protocol 2.0 ("" for a Protocol 2.0 servo)."""
        return protocol1_advice(self.model_number) if self.protocol == 1.0 else ""


def protocol1_advice(model_number: int) -> str:
    """How to bring a servo that answered Protocol 1.0 to Protocol 2.0, which the rig speaks."""
    if model_number in ct.MODELS_BY_NUMBER:
        return (
            "an X-series servo set to Protocol 1.0: with torque off, write 2 to its Protocol Type "
            f"(address 13), e.g. with {WIZARD} (Protocol 1.0 selected to find it, then Protocol Type = "
            "2.0), and scan again"
        )
    if model_number in MX_PROTOCOL_2_NAMES:
        target = MX_PROTOCOL_2_NAMES[model_number]
        supported = target in ct.MODELS
        return (
            f"an MX on Protocol 1.0 firmware: install its Protocol 2.0 firmware ({target}) with {WIZARD}'s "
            "Firmware Recovery"
            + (
                ""
                if supported
                else f"; note that the rig does not support the {target} (current unit 3.36 mA)"
            )
        )
    return (
        "Protocol 1.0 only: the rig cannot drive it (ROBOTIS names the XL430-W250 as the AX-12's successor)"
    )


def protocol1_model_name(model_number: int) -> str:
    """The model name of a number read from a servo answering Protocol 1.0."""
    if model_number in PROTOCOL_1_MODELS:
        return PROTOCOL_1_MODELS[model_number]
    return ct.model_name_for(model_number)


def scan_port(
    port_name: str,
    bauds: Sequence[int],
    *,
    port_factory: Callable[[str], PortHandler] = PortHandler,
    protocol1_ids: Sequence[int] = (),
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
            if protocol1_ids:
                found += _protocol1_sweep(port, port_name, baud, protocol1_ids)
    finally:
        if port is not None and port.is_open:
            with contextlib.suppress(Exception):
                port.closePort()
    return found


def _protocol1_sweep(port: PortHandler, port_name: str, baud: int, ids: Sequence[int]) -> list[ScannedServo]:
    """Ping each ID with Protocol 1.0 at the port's baud rate; the servos that answered."""
    ph = PacketHandler(1.0)
    found: list[ScannedServo] = []
    for servo_id in ids:
        try:
            port.is_using = False
            model_number, result, _ = ph.ping(port, servo_id)
            if result != COMM_SUCCESS:
                continue
            x_series = model_number in ct.MODELS_BY_NUMBER
            address = ct.ADDR_FIRMWARE_VERSION if x_series else ADDR_PROTOCOL_1_FIRMWARE
            firmware, result, _ = ph.read1ByteTxRx(port, servo_id, address)
        except (OSError, serial.SerialException) as exc:
            raise NotConnectedError(f"servo port {port_name} failed: {exc}") from exc
        except (IndexError, ValueError, TypeError, KeyError):
            continue  # a garbled answer: nothing to name
        found.append(
            ScannedServo(
                servo_id,
                model_number,
                protocol1_model_name(model_number),
                int(firmware) if result == COMM_SUCCESS else 0,
                baud,
                protocol=1.0,
            )
        )
    return found


__all__ = ["ScannedServo", "protocol1_advice", "protocol1_model_name", "scan_port"]
