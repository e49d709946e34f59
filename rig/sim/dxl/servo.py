"""One emulated Dynamixel X-series servo: memory image, instruction semantics, faults, motion state.

Pure and clock-free: every entry point takes `now_ns` (integer ns on the bus's clock). The bus
(`rig.sim.dxl.emulated_bus`) frames packets and decides who answers and when; this class decides what a
servo does with one instruction and what it answers.

Semantics (docs/design.md §7; *assumption* where the manual is silent):

* Writes are validated completely before anything is applied. Checks, first failure wins:
  Access (7) for undefined or read-only bytes and for EEPROM (< 64) while Torque Enable = 1;
  Data Length (5) when a field is only partly covered; Data Range (4) outside a field's static
  range (or, after a Bus Watchdog trip, for any goal); Data Limit (6) beyond a configured limit
  (Goal Position outside Min/Max Position Limit in mode 3, |Goal Velocity| > Velocity Limit,
  |Goal Current| > Current Limit, |Goal PWM| > PWM Limit); Result Fail (1) for Torque Enable = 1
  while Hardware Error Status != 0 *(assumption)*.
* Reads beyond the table end give an Access error with no params; bytes in gaps read as 0.
  Indirect Data bytes read and write through their Indirect Address; a write through indirect
  data must still cover whole fields *(assumption)*.
* Instructions are unstuffed on receipt as the spec says, so a raw `FF FF FD FD` in an unstuffed
  SDK write loses one `FD` (as on a spec-following servo); `FF FF FD xx` with xx != FD is intact.
* Operating Mode change: Profile Velocity/Acceleration = 0, Goal PWM = PWM Limit, Goal Current =
  Current Limit; switching to mode 3 folds the multi-turn count into one turn. Torque on: Goal
  Position = Present Position. Reboot (and factory reset): the reply goes out first, then the servo
  is deaf for `boot_time_s`; then RAM is reset, Hardware Error Status cleared, multi-turn lost.
* Overload (0x20): latches when |current| stays at >= 95 % of the lower of the Current Limit and
  the stall current (XL430: the stall current) for `overload_time_s` (default 1.5 s). Mode 5's
  lower Goal Current cap stalls the servo without tripping it. A latched error whose bit is in
  Shutdown (63) turns torque off.
* External torque: the simulated world sets `external_torque_nm` (signed, about the output shaft,
  physical direction) and reads `present_position_rad` etc. back; see `rig.sim.dxl.actuator`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

from rig.hw.dxl import control_table as ct
from rig.hw.dxl.control_table import ControlTable, Field
from rig.sim.dxl import packet as p
from rig.sim.dxl.actuator import ActuatorCommand, ActuatorState, MotorParams, ProfiledActuator
from rig.sim.dxl.shaft_motion import IntegratedShaft

OVERLOAD_FRACTION = 0.95
DEFAULT_OVERLOAD_TIME_S = 1.5
DEFAULT_BOOT_TIME_S = 0.25
WATCHDOG_TRIPPED = ct.BUS_WATCHDOG_TRIPPED  # Bus Watchdog reads -1 after a trip
_INDIRECT_DATA_RANGES = tuple(
    (data_base, data_base + count, addr_base) for addr_base, data_base, count, _ in ct.INDIRECT_ADDRESS_BLOCKS
)
_LOW_INDIRECT = min(r[0] for r in _INDIRECT_DATA_RANGES)


# Realtime Tick (120), then Moving (122) .. Present Input Voltage (144): contiguous in every X430 table,
# as are the registers they are computed from (checked by `_check_layout`).
_TICK = struct.Struct("<H")
_PRESENT_REST = struct.Struct("<BBhhiiiiH")
_ADDR_REALTIME_TICK = 120
_ADDR_HOMING_OFFSET = 20
_HOMING_MOVING = struct.Struct("<iI")  # Homing Offset (20), Moving Threshold (24)
_ADDR_PROFILE_ACCELERATION = 108
# Profile Acceleration (108), Profile Velocity (112), Goal Position (116)
_PROFILE_GOAL = struct.Struct("<IIi")
_LAYOUT = (
    ("Drive Mode", ct.ADDR_DRIVE_MODE, 1),
    ("Homing Offset", _ADDR_HOMING_OFFSET, 4),
    ("Moving Threshold", _ADDR_HOMING_OFFSET + 4, 4),
    ("Torque Enable", ct.ADDR_TORQUE_ENABLE, 1),
    ("Profile Acceleration", _ADDR_PROFILE_ACCELERATION, 4),
    ("Profile Velocity", _ADDR_PROFILE_ACCELERATION + 4, 4),
    ("Goal Position", _ADDR_PROFILE_ACCELERATION + 8, 4),
    ("Realtime Tick", _ADDR_REALTIME_TICK, 2),
    ("Moving", _ADDR_REALTIME_TICK + 2, 1),
    ("Present Input Voltage", _ADDR_REALTIME_TICK + 24, 2),
)


def _check_layout(table: ControlTable) -> None:
    """The fixed addresses `_refresh_present` packs and unpacks must be the table's."""
    for name, address, size in _LAYOUT:
        f = table[name]
        if (f.address, f.size) != (address, size):
            raise ValueError(
                f"{table.model_name}: {name} at {f.address}+{f.size}, the emulator assumes {address}+{size}"
            )


def _clamp(value: int, bits: int) -> int:
    limit = 1 << (bits - 1)
    return max(-limit, min(limit - 1, value))


@dataclass(frozen=True, slots=True)
class Result:
    """What a servo answers to one instruction: ERR number (alert bit added by the bus) and params."""

    error: int = 0
    params: bytes = b""


class Servo(IntegratedShaft):
    """An emulated X-series servo (see the module docstring for its semantics)."""

    def __init__(
        self,
        table: ControlTable,
        servo_id: int = 1,
        *,
        baud: int = 1_000_000,
        firmware: int | None = None,
        motor: MotorParams | None = None,
        overload_time_s: float = DEFAULT_OVERLOAD_TIME_S,
        boot_time_s: float = DEFAULT_BOOT_TIME_S,
        initial_position_rad: float = 0.0,
        supply_voltage_v: float = 12.0,
        now_ns: int = 0,
    ) -> None:
        if not 0 <= servo_id <= p.MAX_ID:
            raise ValueError(f"servo id {servo_id} out of range 0..{p.MAX_ID}")
        if baud not in ct.BAUD_REGISTER_BY_RATE:
            raise ValueError(
                f"baud {baud} is not a Dynamixel rate; allowed: {sorted(ct.BAUD_REGISTER_BY_RATE)}"
            )
        _check_layout(table)
        self.table = table
        self.firmware = table.default_firmware if firmware is None else firmware
        self.motor = motor or MotorParams(
            table.stall_torque_nm, table.stall_current_a, table.no_load_speed_rad_s
        )
        self.actuator = ProfiledActuator(self.motor)
        self.overload_time_ns = round(overload_time_s * 1e9)
        self.boot_time_ns = round(boot_time_s * 1e9)
        self.supply_voltage_v = supply_voltage_v
        # World hook and fault switches.
        self.external_torque_nm = 0.0
        self.silent = False
        # Called as (servo, old_id) after an ID write.
        self.on_id_change: list[Callable[[Servo, int], None]] = []
        # Field handles used on hot paths.
        self._f = {name: table[name] for name in table.names()}
        self._has_current = "Current Limit" in table
        self._mem = bytearray(table.size)
        self._present_key: tuple[object, ...] | None = None  # inputs of the last _refresh_present
        self._load_defaults(keep_id=False, keep_baud=False)
        self._set("ID", servo_id)
        self._set("Baud Rate", ct.BAUD_REGISTER_BY_RATE[baud])
        self._set("Firmware Version", self.firmware)
        # Runtime state.
        self.state = ActuatorState(position_rad=initial_position_rad, ref_position_rad=initial_position_rad)
        self._now_ns = now_ns
        self._turn_offset_pulses = 0  # multi-turn bookkeeping between the shaft angle and the register
        self._fold_to_one_turn()
        self._boot_until_ns = -1
        self._registered: tuple[int, bytes] | None = None
        self._at_limit_ns = 0
        self._last_rx_ns = now_ns
        self._cmd = ActuatorCommand()
        self._settled: tuple[ActuatorCommand, float, float] | None = None  # see _integrate
        self._update_command()

    # ----- register access -------------------------------------------------------------------------------
    def _get(self, name: str) -> int:
        f = self._f[name]
        return int.from_bytes(self._mem[f.address : f.end], "little", signed=f.signed)

    def _set(self, name: str, value: int) -> None:
        self._set_field(self._f[name], value)

    def _set_field(self, f: Field, value: int) -> None:
        self._mem[f.address : f.end] = f.encode(int(value)).to_bytes(f.size, "little")

    def register(self, name: str) -> int:
        """The current value of register `name` (signed where the field is), without side effects."""
        return self._get(name)

    def _load_defaults(self, *, keep_id: bool, keep_baud: bool, ram_only: bool = False) -> None:
        self._present_key = None  # the present registers are reset too
        keep = {}
        if keep_id:
            keep["ID"] = self._get("ID")
        if keep_baud:
            keep["Baud Rate"] = self._get("Baud Rate")
        for f in self.table.fields:
            if ram_only and f.area == "EEPROM":
                continue
            self._set_field(f, f.default)
        if self._has_current:
            self._set("Goal Current", self._get("Current Limit"))
        self._set("Goal PWM", self._get("PWM Limit"))
        self._set("Firmware Version", getattr(self, "firmware", self.table.default_firmware))
        for name, value in keep.items():
            self._set(name, value)

    # ----- identity and state read-backs ----------------------------------------------------------------
    @property
    def servo_id(self) -> int:
        """ID (7)."""
        return self._mem[ct.ADDR_ID]

    @property
    def baud(self) -> int:
        """The baud rate the servo listens at, from Baud Rate (8)."""
        return ct.BAUD_RATES[self._mem[ct.ADDR_BAUD_RATE]]

    def set_baud(self, rate: int) -> None:
        """Fault/scenario hook: move the servo to another standard rate (sets Baud Rate (8))."""
        self._set("Baud Rate", ct.BAUD_REGISTER_BY_RATE[rate])

    @property
    def torque_enabled(self) -> bool:
        """Torque Enable (64)."""
        return self._mem[ct.ADDR_TORQUE_ENABLE] == 1

    @property
    def hardware_error(self) -> int:
        """Hardware Error Status (70) bits."""
        return self._mem[ct.ADDR_HARDWARE_ERROR_STATUS]

    @property
    def operating_mode(self) -> int:
        """Operating Mode (11)."""
        return self._mem[ct.ADDR_OPERATING_MODE]

    @property
    def present_position_rad(self) -> float:
        """Physical output-shaft angle (multi-turn, continuous; unaffected by offsets or reverse)."""
        return self.state.position_rad

    @property
    def present_velocity_rad_s(self) -> float:
        """Physical output-shaft velocity."""
        return self.state.velocity_rad_s

    @property
    def motor_torque_nm(self) -> float:
        """Torque the motor applies to the output shaft (physical direction)."""
        return self.state.motor_torque_nm

    @property
    def present_current_a(self) -> float:
        """Motor current (physical direction) = motor torque / torque constant."""
        return self.state.motor_torque_nm / self.motor.torque_constant_nm_per_a

    def is_booting(self, now_ns: int) -> bool:
        """True while deaf after a reboot or factory reset."""
        if self._boot_until_ns >= 0 and now_ns >= self._boot_until_ns:
            self._finish_boot()
        return self._boot_until_ns >= 0

    def hears(self, now_ns: int, line_baud: int) -> bool:
        """Whether this servo receives traffic at `line_baud` now (not silent, not booting, same rate)."""
        return not self.silent and self.baud == line_baud and not self.is_booting(now_ns)

    # ----- faults ---------------------------------------------------------------------------------------
    def set_temperature_c(self, temperature_c: int) -> None:
        """Present Temperature (146) from now on, in degC (a knob for tests and `rig sim servos`)."""
        self._set("Present Temperature", temperature_c)

    def set_hardware_error(self, bits: int, now_ns: int | None = None) -> None:
        """Latch Hardware Error Status bits (until reboot); torque drops if Shutdown selects any of them."""
        if now_ns is not None:
            self.advance_to(now_ns)
        self._mem[ct.ADDR_HARDWARE_ERROR_STATUS] |= bits & 0xFF
        if bits & self._get("Shutdown") and self.torque_enabled:
            self._set("Torque Enable", 0)
            self._update_command()

    def status_error(self, error: int) -> int:
        """The ERR byte: `error` plus the alert bit while a hardware error is latched."""
        return error | (p.ERR_ALERT if self.hardware_error else 0)

    def replies_to(self, instruction: int) -> bool:
        """Status Return Level (68): 0 = ping only, 1 = ping and reads, 2 = everything."""
        if instruction == p.PING:
            return True
        level = self._mem[68]
        if instruction in (p.READ, p.SYNC_READ, p.BULK_READ, p.FAST_SYNC_READ, p.FAST_BULK_READ):
            return level >= 1
        return level >= 2

    @property
    def supports_fast_read(self) -> bool:
        """Fast Sync/Bulk Read need firmware >= 45."""
        return self.firmware >= ct.FAST_READ_MIN_FIRMWARE

    # ----- physical <-> register mapping ---------------------------------------------------------------
    def _direction(self) -> int:
        return -1 if self._mem[ct.ADDR_DRIVE_MODE] & 0x01 else 1

    def _pulses_from_rad(self, rad: float) -> int:
        return (
            self._direction() * round(rad / ct.RAD_PER_PULSE)
            + self._turn_offset_pulses
            + self._get("Homing Offset")
        )

    def _rad_from_register(self, pulses: int) -> float:
        raw = pulses - self._get("Homing Offset") - self._turn_offset_pulses
        return self._direction() * raw * ct.RAD_PER_PULSE

    def _fold_to_one_turn(self) -> None:
        """Lose the multi-turn count: Present Position (before homing) back into [0, 4096)."""
        shaft = self._direction() * round(self.state.position_rad / ct.RAD_PER_PULSE)
        self._turn_offset_pulses = -(shaft // ct.PULSES_PER_REV) * ct.PULSES_PER_REV

    def _update_command(self) -> None:
        mode = self.operating_mode
        cap_a = (
            (self._get("Current Limit") * ct.CURRENT_UNIT_A)
            if self._has_current
            else self.motor.stall_current_a
        )
        limit_a = cap_a
        if mode == 5 and self._has_current:
            limit_a = min(cap_a, abs(self._get("Goal Current")) * ct.CURRENT_UNIT_A)
        kt = self.motor.torque_constant_nm_per_a
        v_limit = self._get("Velocity Limit") * ct.RAD_S_PER_VELOCITY_UNIT
        prof_v = self._get("Profile Velocity")
        prof_a = self._get("Profile Acceleration")
        time_based = bool(self._mem[ct.ADDR_DRIVE_MODE] & 0x04)
        if time_based:
            v, a = self._time_based_profile(prof_v, prof_a, v_limit)
        else:
            v = min(v_limit, prof_v * ct.RAD_S_PER_VELOCITY_UNIT) if prof_v else v_limit
            a = prof_a * ct.RAD_S2_PER_ACCELERATION_UNIT if prof_a else math.inf
        direction = self._direction()
        goal_current_a = self._get("Goal Current") * ct.CURRENT_UNIT_A if self._has_current else 0.0
        # Used by every integration step; Current Limit and the motor change only with a new command.
        overload_a = self.motor.stall_current_a
        if self._has_current:
            overload_a = min(overload_a, self._get("Current Limit") * ct.CURRENT_UNIT_A)
        self._overload_cap_nm = overload_a * kt * OVERLOAD_FRACTION
        self._coulomb_nm = self.motor.coulomb_nm
        self._cmd = ActuatorCommand(
            torque_enabled=self.torque_enabled,
            mode=mode,
            goal_position_rad=self._rad_from_register(self._get("Goal Position")),
            goal_velocity_rad_s=direction * self._get("Goal Velocity") * ct.RAD_S_PER_VELOCITY_UNIT,
            goal_torque_nm=direction * goal_current_a * kt,
            pwm_fraction=direction * self._get("Goal PWM") / 885.0,
            torque_limit_nm=limit_a * kt,
            profile_velocity_rad_s=v if v > 0 else v_limit,
            profile_acceleration_rad_s2=a,
        )

    def _time_based_profile(self, total_ms: int, accel_ms: int, v_limit: float) -> tuple[float, float]:
        """Drive Mode bit 2: Profile Velocity = move time, Profile Acceleration = ramp time (ms)."""
        if total_ms <= 0:
            return v_limit, math.inf
        distance = abs(self._rad_from_register(self._get("Goal Position")) - self.state.ref_position_rad)
        t_total = total_ms / 1000.0
        t_acc = min(accel_ms, total_ms // 2) / 1000.0
        v = distance / max(t_total - t_acc, 1e-6)
        a = v / t_acc if t_acc > 0 else math.inf
        return min(v, v_limit) if v > 0 else v_limit, a

    # ----- time --------------------------------------------------------------------------------------
    def advance_to(self, now_ns: int) -> None:
        """Integrate motion up to `now_ns`; cheap and idempotent (no-op when `now_ns` is not later)."""
        if now_ns <= self._now_ns:
            return
        if self._boot_until_ns >= 0 and now_ns >= self._boot_until_ns:
            self._integrate(self._boot_until_ns)
            self._finish_boot()
        self._integrate(now_ns)
        if self._mem[98]:  # Bus Watchdog enabled (or tripped)
            self._check_watchdog(now_ns)

    def _on_overload(self) -> None:
        self.set_hardware_error(ct.HW_ERROR_OVERLOAD)

    def _check_watchdog(self, now_ns: int) -> None:
        wd = self._mem[98]
        if wd == 0 or wd == WATCHDOG_TRIPPED or not self.torque_enabled:
            return
        if now_ns - self._last_rx_ns > wd * round(ct.BUS_WATCHDOG_UNIT_S * 1e9):
            self._mem[98] = WATCHDOG_TRIPPED
            self._hold_here()

    def _hold_here(self) -> None:
        """Stop where the shaft is: goal position = present, goal velocity/PWM = 0 as the mode needs."""
        self._set("Goal Position", self._pulses_from_rad(self.state.position_rad))
        self._set("Goal Velocity", 0)
        self.state.ref_position_rad, self.state.ref_velocity_rad_s = self.state.position_rad, 0.0
        self.state.profile_done = True
        self._update_command()

    def note_traffic(self, now_ns: int) -> None:
        """An instruction reached this servo (feeds the Bus Watchdog)."""
        self._last_rx_ns = now_ns

    # ----- present values ---------------------------------------------------------------------------------
    def _refresh_present(self, now_ns: int) -> None:
        """Write the Present/trajectory/status registers (120-146) from the motion state at `now_ns`."""
        self.advance_to(now_ns)
        mem = self._mem
        s = self.state
        _TICK.pack_into(mem, _ADDR_REALTIME_TICK, (now_ns // 1_000_000) % 32768)
        homing, moving_threshold = _HOMING_MOVING.unpack_from(mem, _ADDR_HOMING_OFFSET)
        profile_acceleration, profile_velocity, goal = _PROFILE_GOAL.unpack_from(
            mem, _ADDR_PROFILE_ACCELERATION
        )
        # Everything the rest of the block is computed from; when none of it changed since the last
        # refresh (a servo holding still), the bytes already in memory are the answer.
        key = (
            s.position_rad,
            s.velocity_rad_s,
            s.motor_torque_nm,
            s.ref_position_rad,
            s.ref_velocity_rad_s,
            s.profile_done,
            s.saturated,
            mem[ct.ADDR_DRIVE_MODE],
            mem[ct.ADDR_TORQUE_ENABLE],
            homing,
            moving_threshold,
            profile_acceleration,
            profile_velocity,
            goal,
            self._turn_offset_pulses,
            self.supply_voltage_v,
            self.motor,
        )
        if key == self._present_key:
            return
        self._present_key = key
        direction = -1 if mem[ct.ADDR_DRIVE_MODE] & 0x01 else 1
        offset_pulses = self._turn_offset_pulses + homing
        torque_on = mem[ct.ADDR_TORQUE_ENABLE] == 1
        motor = self.motor
        tau_fraction = max(-1.0, min(1.0, direction * s.motor_torque_nm / motor.stall_torque_nm))
        pwm = round(885 * tau_fraction) if torque_on else 0
        if self._has_current:
            current = round(
                direction * s.motor_torque_nm / motor.torque_constant_nm_per_a / ct.CURRENT_UNIT_A
            )
        else:
            current = round(1000 * tau_fraction)  # XL430 Present Load, 0.1 % of stall torque
        velocity = round(direction * s.velocity_rad_s / ct.RAD_S_PER_VELOCITY_UNIT)
        present = direction * round(s.position_rad / ct.RAD_PER_PULSE) + offset_pulses
        status = 0
        if torque_on:
            if s.profile_done and abs(goal - present) <= 1:
                status |= 0x01
            if not s.profile_done:
                status |= 0x02
            if s.saturated:
                status |= 0x08
            status |= 0x30 if profile_acceleration else (0x10 if profile_velocity else 0)
        _PRESENT_REST.pack_into(
            mem,
            _ADDR_REALTIME_TICK + 2,
            1 if abs(velocity) > moving_threshold else 0,
            status,
            pwm,
            _clamp(current, 16),
            _clamp(velocity, 32),
            _clamp(present, 32),
            _clamp(round(direction * s.ref_velocity_rad_s / ct.RAD_S_PER_VELOCITY_UNIT), 32),
            _clamp(direction * round(s.ref_position_rad / ct.RAD_PER_PULSE) + offset_pulses, 32),
            round(self.supply_voltage_v / ct.VOLTAGE_UNIT_V),
        )

    # ----- instructions -----------------------------------------------------------------------------------
    def ping(self) -> Result:
        """Model number (LSB, MSB) and firmware version."""
        model = self.table.model_number
        return Result(0, bytes((model & 0xFF, model >> 8, self.firmware)))

    def read(self, address: int, length: int, now_ns: int) -> Result:
        """Read `length` bytes at `address` (Access error, no params, beyond the table)."""
        if length < 1:
            return Result(p.ERR_DATA_LENGTH)
        end = address + length
        if end > self.table.size:
            return Result(p.ERR_ACCESS)
        if address < 147:
            self._refresh_present(now_ns)
        data = self._mem[address:end]
        if end > _LOW_INDIRECT:
            for data_lo, data_hi, addr_base in _INDIRECT_DATA_RANGES:
                for a in range(max(address, data_lo), min(end, data_hi)):
                    k = a - data_lo
                    target = self._mem[addr_base + 2 * k] | (self._mem[addr_base + 2 * k + 1] << 8)
                    if target < 147:
                        self._refresh_present(now_ns)
                    data[a - address] = self._mem[target] if target < self.table.size else 0
        return Result(0, bytes(data))

    def _resolve_targets(self, address: int, data: bytes) -> list[tuple[int, int]]:
        """(target address, byte) pairs for a write, with indirect data bytes resolved to their targets."""
        pairs: list[tuple[int, int]] = []
        for i, b in enumerate(data):
            a = address + i
            target = a
            for data_lo, data_hi, addr_base in _INDIRECT_DATA_RANGES:
                if data_lo <= a < data_hi:
                    k = a - data_lo
                    target = self._mem[addr_base + 2 * k] | (self._mem[addr_base + 2 * k + 1] << 8)
                    break
            pairs.append((target, b))
        return pairs

    def _plan_write(self, address: int, data: bytes) -> tuple[int, list[tuple[Field, int]]]:
        """Validate a write without applying it: (error number or 0, [(field, value)])."""
        n = len(data)
        if n < 1:
            return p.ERR_DATA_LENGTH, []
        if address + n > self.table.size:
            return p.ERR_ACCESS, []
        if address + n > _LOW_INDIRECT and any(
            lo < address + n and address < hi for lo, hi, _ in _INDIRECT_DATA_RANGES
        ):
            pairs = self._resolve_targets(address, data)
        else:
            pairs = [(address + i, b) for i, b in enumerate(data)]
        byte_at = dict(pairs)
        if len(byte_at) != len(pairs):
            return p.ERR_DATA_LENGTH, []  # two indirect bytes aiming at one target
        table = self.table
        torque_on = self.torque_enabled
        planned: list[tuple[Field, int]] = []
        seen: set[str] = set()
        error = 0
        for target, _ in pairs:
            f = table.owner(target)
            if f is None or f.access != "RW" or (f.area == "EEPROM" and torque_on):
                return p.ERR_ACCESS, []
            if f.name in seen:
                continue
            if any(a not in byte_at for a in range(f.address, f.end)):
                error = error or p.ERR_DATA_LENGTH
                continue
            seen.add(f.name)
            raw = int.from_bytes(bytes(byte_at[a] for a in range(f.address, f.end)), "little")
            planned.append((f, f.decode(raw)))
        if error:
            return error, []
        for f, value in planned:
            if not f.in_range(value):
                return p.ERR_DATA_RANGE, []
        return self._check_limits(planned), planned

    def _check_limits(self, planned: list[tuple[Field, int]]) -> int:
        new = {f.name: v for f, v in planned}

        def value(name: str) -> int:
            return new[name] if name in new else self._get(name)

        goals = ("Goal Position", "Goal Velocity", "Goal Current", "Goal PWM")
        if self._mem[98] == WATCHDOG_TRIPPED and "Bus Watchdog" not in new and any(g in new for g in goals):
            return p.ERR_DATA_RANGE
        mode = value("Operating Mode")
        in_limits = value("Min Position Limit") <= new.get("Goal Position", 0) <= value("Max Position Limit")
        if "Goal Position" in new and mode == 3 and not in_limits:
            return p.ERR_DATA_LIMIT
        if "Goal Velocity" in new and abs(new["Goal Velocity"]) > value("Velocity Limit"):
            return p.ERR_DATA_LIMIT
        if "Goal Current" in new and abs(new["Goal Current"]) > value("Current Limit"):
            return p.ERR_DATA_LIMIT
        if "Goal PWM" in new and abs(new["Goal PWM"]) > value("PWM Limit"):
            return p.ERR_DATA_LIMIT
        if new.get("Torque Enable") == 1 and self.hardware_error:
            return p.ERR_RESULT_FAIL
        return 0

    def write(self, address: int, data: bytes, now_ns: int) -> Result:
        """Write (0x03): validate every field, then apply them all with their side effects."""
        self.advance_to(now_ns)
        error, planned = self._plan_write(address, data)
        if error:
            return Result(error)
        self._apply(planned, now_ns)
        return Result()

    def _apply(self, planned: list[tuple[Field, int]], now_ns: int) -> None:
        old_id = self.servo_id
        old_mode = self.operating_mode
        was_on = self.torque_enabled
        names = set()
        for f, v in planned:
            self._set_field(f, v)
            names.add(f.name)
        if "Operating Mode" in names and self.operating_mode != old_mode:
            self._set("Profile Velocity", 0)
            self._set("Profile Acceleration", 0)
            self._set("Goal PWM", self._get("PWM Limit"))
            if self._has_current:
                self._set("Goal Current", self._get("Current Limit"))
            if self.operating_mode == 3:
                self._fold_to_one_turn()
        if "Drive Mode" in names or "Homing Offset" in names:
            self.state.ref_position_rad = self.state.position_rad
        drive_mode = self._mem[ct.ADDR_DRIVE_MODE]
        goal_written = bool(names & {"Goal Position", "Goal Velocity", "Goal Current", "Goal PWM"})
        auto_torque = drive_mode & 0x08 and self.supports_fast_read and not self.hardware_error
        if goal_written and auto_torque and not self.torque_enabled:
            self._mem[ct.ADDR_TORQUE_ENABLE] = 1  # Drive Mode bit 3: a goal turns torque on
        if self.torque_enabled and not was_on:
            # Torque on: hold where the shaft is; a stale goal must not make it jump.
            if "Goal Position" not in names:
                self._set("Goal Position", self._pulses_from_rad(self.state.position_rad))
            self.state.ref_position_rad, self.state.ref_velocity_rad_s = self.state.position_rad, 0.0
            self.state.profile_done = "Goal Position" not in names
            self._last_rx_ns = now_ns
        if "Goal Position" in names:
            self.state.profile_done = False
        self._update_command()
        if self.servo_id != old_id:
            for callback in self.on_id_change:
                callback(self, old_id)

    def reg_write(self, address: int, data: bytes, now_ns: int) -> Result:
        """Reg Write (0x04): validate now, hold until Action; sets Registered Instruction (69)."""
        self.advance_to(now_ns)
        error, _ = self._plan_write(address, data)
        if error:
            return Result(error)
        self._registered = (address, bytes(data))
        self._mem[69] = 1
        return Result()

    def action(self, now_ns: int) -> Result:
        """Action (0x05): apply the registered write; Instruction error without one."""
        if self._registered is None:
            return Result(p.ERR_INSTRUCTION)
        address, data = self._registered
        self._registered = None
        self._mem[69] = 0
        return self.write(address, data, now_ns)

    def reboot(self, now_ns: int) -> Result:
        """Reboot (0x08): answer, then deaf for the boot time; RAM reset when it ends."""
        self.advance_to(now_ns)
        self._boot_until_ns = now_ns + self.boot_time_ns
        return Result()

    def factory_reset(self, option: int, now_ns: int) -> Result:
        """Factory Reset (0x06): 0xFF all, 0x01 all but ID, 0x02 all but ID and baud; then reboot."""
        if option not in (0xFF, 0x01, 0x02):
            return Result(p.ERR_DATA_RANGE)
        if self.torque_enabled:
            return Result(p.ERR_ACCESS)  # EEPROM is locked while torque is on
        self.advance_to(now_ns)
        old_id = self.servo_id
        self._load_defaults(keep_id=option in (0x01, 0x02), keep_baud=option == 0x02)
        self._fold_to_one_turn()
        self._update_command()
        self._boot_until_ns = now_ns + self.boot_time_ns
        if self.servo_id != old_id:
            for callback in self.on_id_change:
                callback(self, old_id)
        return Result()

    def clear(self, params: bytes, now_ns: int) -> Result:
        """Clear (0x10) with `01 44 58 4C 22`: reset the multi-turn count; Result Fail while moving."""
        if params != p.CLEAR_MULTI_TURN_PARAMS:
            return Result(p.ERR_DATA_RANGE)
        self._refresh_present(now_ns)
        if self._mem[122]:
            return Result(p.ERR_RESULT_FAIL)
        self._fold_to_one_turn()
        if self.torque_enabled:
            self._hold_here()
        return Result()

    def _finish_boot(self) -> None:
        self._boot_until_ns = -1
        self._load_defaults(keep_id=True, keep_baud=True, ram_only=True)
        self._mem[ct.ADDR_HARDWARE_ERROR_STATUS] = 0
        self._registered = None
        self._at_limit_ns = 0
        self._fold_to_one_turn()
        self.state.ref_position_rad, self.state.ref_velocity_rad_s = self.state.position_rad, 0.0
        self.state.profile_done = True
        self._update_command()

    def execute(self, instruction: int, params: bytes, now_ns: int) -> Result | None:
        """One unicast or broadcast single-device instruction; None for instructions it drops."""
        self.note_traffic(now_ns)
        if instruction == p.PING:
            return self.ping() if not params else Result(p.ERR_DATA_LENGTH)
        if instruction == p.READ:
            if len(params) != 4:
                return Result(p.ERR_DATA_LENGTH)
            return self.read(p.u16(params, 0), p.u16(params, 2), now_ns)
        if instruction in (p.WRITE, p.REG_WRITE):
            if len(params) < 3:
                return Result(p.ERR_DATA_LENGTH)
            handler = self.write if instruction == p.WRITE else self.reg_write
            return handler(p.u16(params, 0), params[2:], now_ns)
        if instruction == p.ACTION:
            return self.action(now_ns)
        if instruction == p.REBOOT:
            return self.reboot(now_ns)
        if instruction == p.FACTORY_RESET:
            if len(params) != 1:
                return Result(p.ERR_DATA_LENGTH)
            return self.factory_reset(params[0], now_ns)
        if instruction == p.CLEAR:
            return self.clear(params, now_ns)
        return Result(p.ERR_INSTRUCTION)
