"""Decoding Dynamixel error information into words and typed rig errors.

Three sources of trouble, decoded here: the SDK's communication result codes (`COMM_*`), the ERR
byte of every Protocol 2.0 status packet (bit 7 = Alert, bits 0-6 = the error number), and the
Hardware Error Status register (address 70, same bits as Shutdown at 63), which latches until a
reboot. `hardware_fault` builds the one error the runner sees for a latched fault.
"""

from __future__ import annotations

from dynamixel_sdk import (
    COMM_NOT_AVAILABLE,
    COMM_PORT_BUSY,
    COMM_RX_CORRUPT,
    COMM_RX_FAIL,
    COMM_RX_TIMEOUT,
    COMM_RX_WAITING,
    COMM_SUCCESS,
    COMM_TX_ERROR,
    COMM_TX_FAIL,
)

from rig.errors import CommunicationError, HardwareFault
from rig.hw.dxl import control_table as ct

ALERT_BIT = 0x80
ERROR_NUMBER_MASK = 0x7F

# Hardware Error Status (70) bits, X-series; the same bits select the Shutdown (63) conditions.
HARDWARE_ERROR_BITS: dict[int, str] = {
    ct.HW_ERROR_INPUT_VOLTAGE: "input voltage",
    ct.HW_ERROR_OVERHEATING: "overheating",
    ct.HW_ERROR_ENCODER: "encoder",
    ct.HW_ERROR_ELECTRICAL_SHOCK: "electrical shock",
    ct.HW_ERROR_OVERLOAD: "overload",
}

# Protocol 2.0 status ERR byte, bits 0-6 (the emulator, rig.sim.dxl.packet, answers with these).
ERRNUM_RESULT_FAIL = 1
ERRNUM_INSTRUCTION = 2
ERRNUM_CRC = 3
ERRNUM_DATA_RANGE = 4
ERRNUM_DATA_LENGTH = 5
ERRNUM_DATA_LIMIT = 6
ERRNUM_ACCESS = 7
ERROR_NUMBERS: dict[int, str] = {
    ERRNUM_RESULT_FAIL: "result fail",
    ERRNUM_INSTRUCTION: "instruction error",
    ERRNUM_CRC: "CRC error",
    ERRNUM_DATA_RANGE: "data range error",
    ERRNUM_DATA_LENGTH: "data length error",
    ERRNUM_DATA_LIMIT: "data limit error",
    ERRNUM_ACCESS: "access error",
}

COMM_RESULTS: dict[int, str] = {
    COMM_SUCCESS: "success",
    COMM_PORT_BUSY: "port busy",
    COMM_TX_FAIL: "transmit failed",
    COMM_RX_FAIL: "receive failed",
    COMM_TX_ERROR: "invalid instruction packet",
    COMM_RX_WAITING: "still receiving",
    COMM_RX_TIMEOUT: "timeout (no status packet)",
    COMM_RX_CORRUPT: "corrupt status packet",
    COMM_NOT_AVAILABLE: "not available",
}


def hardware_error_words(bits: int) -> list[str]:
    """Hardware Error Status bits as words, e.g. 0x24 -> ["overheating", "overload"]."""
    words = [word for bit, word in HARDWARE_ERROR_BITS.items() if bits & bit]
    unknown = bits & ~sum(HARDWARE_ERROR_BITS) & 0xFF
    if unknown:
        words.append(f"unknown bits 0x{unknown:02X}")
    return words


def describe_hardware_error(bits: int) -> str:
    """One phrase for Hardware Error Status bits: "0x20 (overload)" or "none"."""
    if bits == 0:
        return "none"
    return f"0x{bits:02X} ({', '.join(hardware_error_words(bits))})"


def error_number_name(err: int) -> str:
    """Name of the error number in a status packet's ERR byte (the Alert bit is ignored)."""
    number = err & ERROR_NUMBER_MASK
    return ERROR_NUMBERS.get(number, f"unknown error number {number}")


def comm_result_name(result: int) -> str:
    """Name of a dynamixel-sdk `COMM_*` result code."""
    return COMM_RESULTS.get(result, f"unknown result {result}")


def servo_label(servo_id: int, role: str | None) -> str:
    """How messages name a servo: "servo 2 (winch)"."""
    return f"servo {servo_id} ({role})" if role else f"servo {servo_id}"


class ServoHardwareFault(HardwareFault):
    """A latched Dynamixel hardware error; `servo_id`, `role` and `hardware_error` (bits) are attributes."""

    def __init__(self, message: str, servo_id: int, role: str | None, hardware_error: int) -> None:
        super().__init__(message)
        self.servo_id = servo_id
        self.role = role
        self.hardware_error = hardware_error

    @property
    def words(self) -> list[str]:
        """The decoded hardware error bits."""
        return hardware_error_words(self.hardware_error)


def hardware_fault(servo_id: int, role: str | None, bits: int, context: str = "") -> ServoHardwareFault:
    """The error for a latched hardware error, naming the servo, its role and the decoded words."""
    where = f" during {context}" if context else ""
    return ServoHardwareFault(
        f"{servo_label(servo_id, role)}: hardware error {describe_hardware_error(bits)}{where}; "
        "torque is off and only a reboot clears it",
        servo_id,
        role,
        bits,
    )


class InstructionRejected(CommunicationError):
    """A servo answered with a non-zero error number: it received the instruction and refused it.

    `servo_id` and `error_number` (1-7, see `ERROR_NUMBERS`) are attributes. Not retried, except
    for a CRC error (the instruction was corrupted in transit).
    """

    def __init__(self, message: str, servo_id: int, error_number: int) -> None:
        super().__init__(message)
        self.servo_id = servo_id
        self.error_number = error_number
