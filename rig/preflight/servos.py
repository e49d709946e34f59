"""Pre-flight section `servos`: every configured servo found, its model, firmware, supply, heat and errors.

The bus is connected as a run connects it (the handshake pings every configured ID and compares the
model number; the connect writes Return Delay Time, Status Return Level and the Bus Watchdog, and
moves nothing). Then, per servo: the firmware against the Bus Watchdog's minimum (v38, ROBOTIS
e-manual) and Fast Sync Read's (v45); Present Input Voltage (144) against the model's specified
range (`rig.inputs.servo_ratings.INPUT_VOLTAGE_RANGE_V`); Present Temperature (146) against the model's
default Temperature Limit (31); Hardware Error Status (70); and the operating mode its role needs
(the winch current-based position, 5; a bender extended position, 4). Not verified on hardware.
"""

from __future__ import annotations

from rig.errors import HandshakeError
from rig.hw.dxl import control_table as ct
from rig.hw.dxl.bus import ServoHealthReport, ServoInfo
from rig.hw.dxl.error_codes import describe_hardware_error
from rig.hw.seams import OperatingMode
from rig.inputs.rig_config import RigConfig
from rig.inputs.servo_ratings import BUS_WATCHDOG_MIN_FIRMWARE, INPUT_VOLTAGE_RANGE_V
from rig.preflight.check_context import CheckContext
from rig.preflight.verdicts import CheckRow, Verdict
from rig.vocabulary import ServoModel, ServoRole

SECTION = "servos"
# A servo this close to its Temperature Limit gets a warning: a ramp heats the winch further.
TEMPERATURE_MARGIN_C = 15.0
MODE_FOR_ROLE = {
    ServoRole.WINCH: OperatingMode.CURRENT_BASED_POSITION,
    ServoRole.BENDER: OperatingMode.EXTENDED_POSITION,
}
FIRMWARE_FIX = (
    "update the firmware with DYNAMIXEL Wizard 2.0 (Tools > Firmware Update; one servo at a time on "
    "the U2D2), then run `rig check` again"
)


def servo_rows(ctx: CheckContext) -> list[CheckRow]:
    """Connect the bus and check every configured servo."""
    config = ctx.config
    bus = ctx.servo_bus()
    ids = ", ".join(str(s.servo_id) for s in config.servos.servos)
    where = f"{config.servos.port} at {config.servos.baud} baud"
    if bus is None:
        fix = _not_found_fix(config, ctx.servo_handshake)
        return [CheckRow(SECTION, f"servos {ids} found", Verdict.FAIL, f"{where}: {ctx.servo_failure}", fix)]
    rows = [CheckRow(SECTION, f"servos {ids} found", Verdict.PASS, f"{where}: every configured ID answered")]
    health = bus.read_health()
    for servo_id, info in bus.info().items():
        rows += servo_checks(info, health[servo_id])
    return rows


def _not_found_fix(config: RigConfig, handshake: HandshakeError | None) -> str:
    """What to do when the bus did not connect: fix a wrong model (config or servo), else find the servos."""
    fixes = []
    for servo_id, found in handshake.wrong_models if handshake is not None else ():
        index = next(i for i, s in enumerate(config.servos.servos) if s.servo_id == servo_id)
        if found in set(ServoModel):
            fixes.append(
                f"servo {servo_id} answers as {found}: if that is the servo you mean, set "
                f"servos.ids[{index}].model: {found} in {config.source}; else put a "
                f"{config.servos.servos[index].model} on ID {servo_id}"
            )
        else:
            fixes.append(
                f"servo {servo_id} answers as a model the rig does not know ({found}); put one of "
                f"{', '.join(ServoModel)} on ID {servo_id}"
            )
    if handshake is None or handshake.missing_ids or not fixes:
        fixes.append(
            f"`rig scan --port {config.servos.port}` lists the servos that answer, with their IDs, models "
            f"and baud rates; `rig setup-servos --rig {config.source}` gives each servo its ID and the bus "
            "baud, one servo at a time (or DYNAMIXEL Wizard 2.0); check that the servo supply is on (the "
            "U2D2 does not power the servos)"
        )
    return "; ".join(fixes)


def servo_checks(info: ServoInfo, health: ServoHealthReport) -> list[CheckRow]:
    """The rows of one found servo."""
    label = f"servo {info.servo_id} ({info.role})"
    model = ServoModel(info.model)
    table = ct.MODELS[model]
    rows = [
        CheckRow(SECTION, f"{label} model", Verdict.PASS, f"{info.model} (model number {info.model_number})"),
        _firmware_row(label, info.firmware),
        _voltage_row(label, model, health.input_voltage_v),
        _temperature_row(label, table, health.temperature_c),
        _error_row(label, health.hardware_error),
    ]
    mode = MODE_FOR_ROLE.get(ServoRole(info.role))
    if mode is not None:
        ok = int(mode) in table.operating_modes
        rows.append(
            CheckRow(
                SECTION,
                f"{label} operating mode",
                Verdict.PASS if ok else Verdict.FAIL,
                f"{info.role} needs mode {int(mode)} ({mode.name.lower()}); {info.model} offers "
                f"{sorted(table.operating_modes)}",
                "" if ok else f"use a model with mode {int(mode)} for the {info.role}",
            )
        )
    return rows


def _firmware_row(label: str, firmware: int) -> CheckRow:
    check = f"{label} firmware"
    if firmware < BUS_WATCHDOG_MIN_FIRMWARE:
        return CheckRow(
            SECTION,
            check,
            Verdict.FAIL,
            f"v{firmware}: no Bus Watchdog (needs v{BUS_WATCHDOG_MIN_FIRMWARE} or later), so a servo "
            "keeps its last goal if the host stops",
            FIRMWARE_FIX,
        )
    if firmware < ct.FAST_READ_MIN_FIRMWARE:
        return CheckRow(
            SECTION,
            check,
            Verdict.WARN,
            f"v{firmware}: Bus Watchdog yes; Fast Sync Read needs v{ct.FAST_READ_MIN_FIRMWARE} (a plain "
            "Sync Read is used, slower per tick)",
            FIRMWARE_FIX,
        )
    return CheckRow(SECTION, check, Verdict.PASS, f"v{firmware}: Bus Watchdog and Fast Sync Read")


def _voltage_row(label: str, model: ServoModel, voltage_v: float) -> CheckRow:
    low_v, high_v = INPUT_VOLTAGE_RANGE_V[model]
    measured = f"{voltage_v:.1f} V ({model} is specified for {low_v:g}-{high_v:g} V)"
    if low_v <= voltage_v <= high_v:
        return CheckRow(SECTION, f"{label} input voltage", Verdict.PASS, measured)
    fix = (
        f"set the servo supply to {low_v:g}-{high_v:g} V; a low reading under no load also means a "
        "thin or long supply lead, or an e-stop contact with resistance"
    )
    return CheckRow(SECTION, f"{label} input voltage", Verdict.FAIL, measured, fix)


def _temperature_row(label: str, table: ct.ControlTable, temperature_c: float) -> CheckRow:
    limit_c = table["Temperature Limit"].default
    measured = f"{temperature_c:.0f} degC (Temperature Limit {limit_c} degC)"
    check = f"{label} temperature"
    if temperature_c >= limit_c:
        fix = "let it cool with torque off; it shuts down (overheating) at its limit"
        return CheckRow(SECTION, check, Verdict.FAIL, measured, fix)
    if temperature_c >= limit_c - TEMPERATURE_MARGIN_C:
        fix = "let it cool before a long run: a stalled winch heats quickly"
        return CheckRow(SECTION, check, Verdict.WARN, measured, fix)
    return CheckRow(SECTION, check, Verdict.PASS, measured)


def _error_row(label: str, bits: int) -> CheckRow:
    check = f"{label} hardware error"
    if not bits:
        return CheckRow(SECTION, check, Verdict.PASS, "none")
    fix = (
        "find the cause first (an overload: a stalled or jammed winch; input voltage: the supply), then "
        "clear it by power-cycling the servo or rebooting it in DYNAMIXEL Wizard 2.0; only a reboot "
        "clears it and lets torque back on"
    )
    return CheckRow(SECTION, check, Verdict.FAIL, describe_hardware_error(bits), fix)
