"""Object-level simulated devices: a `ServoBus` and a `LoadCell` that drive `SimWorld` without bytes.

The byte-level simulated rig runs the real drivers against emulators (Dynamixel packets, load-cell
lines). For statistics over many seeds those bytes add cost and nothing else, so these devices
implement the seams (`rig.hw.seams`) directly on the same models:

* `ObjectServoBus`: each servo is the emulator's motion model (`rig.sim.dxl.actuator`:
  profile generator + saturating quasi-static motor, the one the byte-level `Servo` integrates),
  stepped in the same 1 ms substeps, with the world's `external_torque_nm` on its shaft. Commands and
  read-backs are quantised to the device's units (position pulses, 2.69 mA current, 0.229 rpm
  velocity and profile units) exactly as the driver and the emulated registers quantise them, so the
  runner sees the same resolution. Modelled: position modes 3, 4, 5, torque, profile, current limit
  and goal current, the overload latch (and the torque-off it triggers), reboot. Not modelled (no
  fault can reach them here): packet errors, the bus watchdog, the multi-turn fold of mode 3.
* `ObjectLoadCell`: the emulator's signal model (`SignalModel.counts`: gain, offset, drift, noise,
  quantisation, ADC clamp) at the emulator's sample times and rate, with the same seeded noise
  sequence (Box-Muller pairs from `random.Random(seed)`, which is `random.gauss`), calibrated by the
  ideal calibration; samples taken while the cell is closed are lost, as on the wire.

The one thing that differs from the byte level is time: bus transactions take no virtual time
here, so the winch's motion and the load-cell samples fall a fraction of a millisecond apart from
a byte-level run of the same seed (see tests/test_study_devices.py for what that changes).
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from model.gravity import STANDARD_GRAVITY_M_S2
from rig.errors import HardwareFault, LimitError
from rig.hw.dxl import control_table as ct
from rig.hw.dxl import units
from rig.hw.loadcell.calibration import Calibration
from rig.hw.seams import LoadCellSample, OperatingMode, ServoState
from rig.sim.dxl.actuator import POSITION_MODES, ActuatorCommand, ActuatorState, MotorParams, ProfiledActuator
from rig.sim.dxl.servo import DEFAULT_BOOT_TIME_S, DEFAULT_OVERLOAD_TIME_S, OVERLOAD_FRACTION
from rig.sim.dxl.shaft_motion import IntegratedShaft
from rig.sim.loadcell.artefacts import ArtefactModel
from rig.sim.loadcell.emulator import MAX_RATE_HZ, MIN_RATE_HZ, SignalModel, TensionSource
from rig.sim.virtual_clock import VirtualClock

_SUPPORTED_MODES = frozenset(int(m) for m in POSITION_MODES)


class ObjectServo(IntegratedShaft):
    """One servo as a motion model with registers in physical units (a `ShaftLike` for the world)."""

    def __init__(self, servo_id: int, model: str, now_ns: int) -> None:
        table = ct.table_for_model(model)
        self.servo_id = servo_id
        self.table = table
        self.motor = MotorParams(table.stall_torque_nm, table.stall_current_a, table.no_load_speed_rad_s)
        self.actuator = ProfiledActuator(self.motor)
        self._coulomb_nm = self.motor.coulomb_nm  # a computed property; read every millisecond
        self.overload_time_ns = round(DEFAULT_OVERLOAD_TIME_S * 1e9)
        self.state = ActuatorState()
        self.external_torque_nm = 0.0  # set by the world
        self.mode = int(table["Operating Mode"].default)
        self.torque_enabled = False
        self.torque_wanted = False  # what the host last asked for; a reboot restores it, as the driver does
        self.hardware_error = 0
        self.goal_pulses = 0
        self.profile_velocity_units = 0
        self.profile_acceleration_units = 0
        self.has_current = "Current Limit" in table
        self.current_limit_units = int(table["Current Limit"].default) if self.has_current else 0
        self.goal_current_units = self.current_limit_units
        self.velocity_limit_units = int(table["Velocity Limit"].default)
        self.moving_threshold_units = int(table["Moving Threshold"].default)
        self.shutdown_bits = int(table["Shutdown"].default)
        self._now_ns = now_ns
        self._at_limit_ns = 0
        self._cmd = ActuatorCommand()
        self._settled: tuple[ActuatorCommand, float, float] | None = None
        self.update_command()

    @property
    def present_position_rad(self) -> float:
        """Physical output-shaft angle (what the world winds the line with)."""
        return self.state.position_rad

    def update_command(self) -> None:
        """Turn the settings into the actuator's command (as the emulated servo does from its registers)."""
        kt = self.motor.torque_constant_nm_per_a
        cap_a = (
            self.current_limit_units * ct.CURRENT_UNIT_A if self.has_current else self.motor.stall_current_a
        )
        limit_a = cap_a
        if self.mode == OperatingMode.CURRENT_BASED_POSITION and self.has_current:
            limit_a = min(cap_a, abs(self.goal_current_units) * ct.CURRENT_UNIT_A)
        v_limit = self.velocity_limit_units * ct.RAD_S_PER_VELOCITY_UNIT
        prof_v = self.profile_velocity_units
        v = min(v_limit, prof_v * ct.RAD_S_PER_VELOCITY_UNIT) if prof_v else v_limit
        prof_a = self.profile_acceleration_units
        a = prof_a * ct.RAD_S2_PER_ACCELERATION_UNIT if prof_a else math.inf
        self._overload_cap_nm = min(self.motor.stall_current_a, cap_a) * kt * OVERLOAD_FRACTION
        self._cmd = ActuatorCommand(
            torque_enabled=self.torque_enabled,
            mode=self.mode,
            goal_position_rad=self.goal_pulses * ct.RAD_PER_PULSE,
            torque_limit_nm=limit_a * kt,
            profile_velocity_rad_s=v if v > 0 else v_limit,
            profile_acceleration_rad_s2=a,
        )

    def advance_to(self, now_ns: int) -> None:
        """Integrate the motion to `now_ns` (`IntegratedShaft`: the emulated servo's very steps)."""
        self._integrate(now_ns)

    def _on_overload(self) -> None:
        self.set_hardware_error(ct.HW_ERROR_OVERLOAD)

    def set_hardware_error(self, bits: int) -> None:
        """Latch Hardware Error Status bits (until reboot); torque drops if Shutdown selects any of them."""
        self.hardware_error |= bits & 0xFF
        if bits & self.shutdown_bits and self.torque_enabled:
            self.torque_enabled = False
            self.update_command()

    def hold_here(self) -> None:
        """Goal = present position and the profile reference with it (torque on without a jump)."""
        self.goal_pulses = units.pulses_from_position_rad(self.state.position_rad)
        self.state.ref_position_rad = self.goal_pulses * ct.RAD_PER_PULSE
        self.state.ref_velocity_rad_s = 0.0

    def read_state(self, time_ns: int) -> ServoState:
        """The state as the driver decodes it from the registers (quantised)."""
        s = self.state
        velocity_units = units.velocity_units_from_rad_s(s.velocity_rad_s)
        current_a = (
            units.current_units_from_a(s.motor_torque_nm / self.motor.torque_constant_nm_per_a)
            * ct.CURRENT_UNIT_A
            if self.has_current
            else math.nan
        )
        return ServoState(
            servo_id=self.servo_id,
            position_rad=units.pulses_from_position_rad(s.position_rad) * ct.RAD_PER_PULSE,
            velocity_rad_s=velocity_units * ct.RAD_S_PER_VELOCITY_UNIT,
            current_a=current_a,
            hardware_error=self.hardware_error,
            moving=abs(velocity_units) > self.moving_threshold_units,
            time_ns=time_ns,
        )


class ObjectServoBus:
    """A `ServoBus` over `ObjectServo`s in virtual time; `advance_to` is the world's `step_devices`."""

    def __init__(self, clock: VirtualClock, servos: Sequence[tuple[int, str]]) -> None:
        self.clock = clock
        now = clock.monotonic_ns()
        self.servos = [ObjectServo(sid, model, now) for sid, model in servos]
        self._by_id = {s.servo_id: s for s in self.servos}
        self._connected = False

    def servo(self, servo_id: int) -> ObjectServo:
        """The servo with `servo_id` (`LimitError` if none)."""
        try:
            return self._by_id[servo_id]
        except KeyError:
            raise LimitError(f"servo {servo_id}: not on the bus (ids: {sorted(self._by_id)})") from None

    def advance_to(self, now_ns: int) -> None:
        """Integrate every servo's motion up to `now_ns`."""
        for servo in self.servos:
            if now_ns > servo._now_ns:
                servo._integrate(now_ns)  # ObjectServo.advance_to, without the extra call

    def at_rest(self) -> bool:
        """True if no servo would move (nor change) until the world changes its load (`SimWorld`)."""
        return all(servo._at_rest() for servo in self.servos)

    def set_hardware_error(self, servo_id: int, bits: int) -> None:
        """Latch Hardware Error Status bits on a servo now (fault injection, as `EmulatedBus` offers)."""
        servo = self.servo(servo_id)
        servo.advance_to(self.clock.monotonic_ns())
        servo.set_hardware_error(bits)

    def connect(self) -> None:
        """Nothing to open: every servo is there."""
        self._connected = True

    def read_states(self) -> dict[int, ServoState]:
        """Every servo's state now, quantised as the driver reads it."""
        now = self.clock.monotonic_ns()
        self.advance_to(now)
        time_ns = self.clock.time_ns()
        return {s.servo_id: s.read_state(time_ns) for s in self.servos}

    def set_operating_mode(
        self,
        servo_id: int,
        mode: OperatingMode,
        *,
        goal_current_a: float | None = None,
        profile_velocity_rad_s: float | None = None,
        profile_acceleration_rad_s2: float | None = None,
    ) -> None:
        """Switch the mode; goal current and profile rewritten (given values, else those in force)."""
        servo = self.servo(servo_id)
        if int(mode) not in _SUPPORTED_MODES:
            raise LimitError(
                f"servo {servo_id}: operating mode {int(mode)} is not modelled by the object-level devices; "
                f"allowed: {sorted(_SUPPORTED_MODES)} (use the byte-level devices)"
            )
        if goal_current_a is not None:
            servo.goal_current_units = self._current_units(servo, goal_current_a)
        self.set_profile(servo_id, profile_velocity_rad_s, profile_acceleration_rad_s2)
        servo.mode = int(mode)
        if servo.torque_enabled:
            servo.hold_here()
        servo.update_command()

    def set_torque(self, servo_ids: Sequence[int], enabled: bool) -> None:
        """Torque on (in place, refused with a latched error) or off."""
        for servo_id in servo_ids:
            servo = self.servo(servo_id)
            servo.advance_to(self.clock.monotonic_ns())
            if enabled and servo.hardware_error:
                raise HardwareFault(
                    f"servo {servo_id}: hardware error 0x{servo.hardware_error:02x} latched; reboot it first"
                )
            if enabled and not servo.torque_enabled:
                servo.hold_here()
            servo.torque_enabled = servo.torque_wanted = enabled
            servo.update_command()

    def set_profile(
        self, servo_id: int, velocity_rad_s: float | None = None, acceleration_rad_s2: float | None = None
    ) -> None:
        """Profile Velocity / Acceleration in the device's units (None keeps the value in force)."""
        servo = self.servo(servo_id)
        servo.advance_to(self.clock.monotonic_ns())
        for name, value in (("velocity", velocity_rad_s), ("acceleration", acceleration_rad_s2)):
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise LimitError(f"servo {servo_id}: profile {name} {value} must be >= 0 and finite")
        if velocity_rad_s is not None:
            servo.profile_velocity_units = units.velocity_units_from_rad_s(velocity_rad_s)
        if acceleration_rad_s2 is not None:
            servo.profile_acceleration_units = units.acceleration_units_from_rad_s2(acceleration_rad_s2)
        servo.update_command()

    def set_current_limit(self, servo_id: int, current_limit_a: float) -> None:
        """Current Limit; a goal current beyond it is cut back to it."""
        servo = self.servo(servo_id)
        servo.advance_to(self.clock.monotonic_ns())
        if not servo.has_current:
            raise LimitError(f"servo {servo_id}: model {servo.table.model_name} has no Current Limit")
        field = servo.table["Current Limit"]
        value = units.current_units_from_a(current_limit_a)
        if not field.min <= value <= field.max:
            raise LimitError(
                f"servo {servo_id}: current limit {current_limit_a:.3f} A is outside "
                f"[{field.min * ct.CURRENT_UNIT_A:.3f}, {field.max * ct.CURRENT_UNIT_A:.3f}] A"
            )
        servo.current_limit_units = value
        if abs(servo.goal_current_units) > value:
            servo.goal_current_units = value if servo.goal_current_units > 0 else -value
        servo.update_command()

    def write_goal_positions(self, goals_rad: Mapping[int, float]) -> None:
        """Goal positions, to the nearest pulse (position modes only)."""
        now = self.clock.monotonic_ns()
        pulses: dict[int, int] = {}
        for servo_id, goal_rad in goals_rad.items():
            servo = self.servo(servo_id)
            if not math.isfinite(goal_rad):
                raise LimitError(f"servo {servo_id}: goal position {goal_rad} rad is not a finite number")
            if servo.mode not in _SUPPORTED_MODES:
                raise LimitError(f"servo {servo_id}: goal positions need mode 3, 4 or 5")
            pulses[servo_id] = units.pulses_from_position_rad(goal_rad)
        for servo_id, value in pulses.items():
            servo = self._by_id[servo_id]
            servo.advance_to(now)
            servo.goal_pulses = value
            servo.update_command()

    def write_goal_currents(self, goals_a: Mapping[int, float]) -> None:
        """Goal currents within +-Current Limit (in mode 5 they cap the torque)."""
        now = self.clock.monotonic_ns()
        checked = {sid: self._current_units(self.servo(sid), a) for sid, a in goals_a.items()}
        for servo_id, value in checked.items():
            servo = self._by_id[servo_id]
            servo.advance_to(now)
            servo.goal_current_units = value
            servo.update_command()

    def _current_units(self, servo: ObjectServo, goal_a: float) -> int:
        if not servo.has_current:
            raise LimitError(f"servo {servo.servo_id}: model {servo.table.model_name} has no current control")
        if not math.isfinite(goal_a):
            raise LimitError(f"servo {servo.servo_id}: goal current {goal_a} A is not a finite number")
        value = units.current_units_from_a(goal_a)
        if abs(value) > servo.current_limit_units:
            raise LimitError(
                f"servo {servo.servo_id}: goal current {goal_a:.3f} A is outside "
                f"+-{servo.current_limit_units * ct.CURRENT_UNIT_A:.3f} A (Current Limit)"
            )
        return value

    def reboot(self, servo_id: int) -> None:
        """Clear a latched error: the servo restarts after its boot time, its settings restored.

        The servo itself comes back with RAM defaults and torque off; the driver
        (`DynamixelServoBus.reboot`) then writes back the goal current and profile it had set and
        turns the torque on in place if the host had it on, so that is what this bus does too.
        """
        servo = self.servo(servo_id)
        servo.advance_to(self.clock.monotonic_ns())
        goal_current = servo.goal_current_units
        profile = (servo.profile_velocity_units, servo.profile_acceleration_units)
        self.clock.sleep(DEFAULT_BOOT_TIME_S)
        servo.hardware_error = 0
        servo.goal_current_units = goal_current
        servo.profile_velocity_units, servo.profile_acceleration_units = profile
        servo.hold_here()
        servo.torque_enabled = servo.torque_wanted
        servo.update_command()

    def shutdown(self, release: Callable[[], None] | None = None) -> None:
        """Run `release`, then torque off every servo; re-raise the first error."""
        first: BaseException | None = None
        if release is not None:
            try:
                release()
            except BaseException as exc:  # torque goes off whatever happened
                first = exc
        for servo in self.servos:
            servo.advance_to(self.clock.monotonic_ns())
            servo.torque_enabled = False
            servo.update_command()
        self._connected = False
        if first is not None:
            raise first


def object_calibration(signal: SignalModel) -> Calibration:
    """The calibration a perfect two-point procedure finds for `signal` (the byte-level rig's too)."""
    return Calibration(
        factor_n_per_count=1.0 / signal.gain_counts_per_n,
        offset_counts=signal.offset_counts,
        reference_mass_kg=None,
        g=STANDARD_GRAVITY_M_S2,
        date="2026-01-01T00:00:00+00:00",
        serial="sim",
        format="object",
        noise_counts=signal.noise_counts,
    )


def gauss_draws(rng: random.Random, count: int) -> list[float]:
    """`count` draws of `rng.gauss(0.0, 1.0)`: the same numbers, and `rng` left in the same state.

    Fast path of `[rng.gauss(0.0, 1.0) for _ in range(count)]`: CPython's Box-Muller pairs
    (`random.Random.gauss`, its `gauss_next` cache included) spelled out in one loop;
    tests/test_sim_fast_paths.py holds it equal to `gauss`.
    """
    out: list[float] = []
    if count <= 0:
        return out
    cache: Any = rng  # `gauss_next` is CPython's (not in the type stubs)
    z = cache.gauss_next
    cache.gauss_next = None
    if z is not None:
        out.append(0.0 + z * 1.0)  # mu + z * sigma
        count -= 1
    uniform, two_pi = rng.random, 2.0 * math.pi
    log, sqrt, cos, sin = math.log, math.sqrt, math.cos, math.sin
    while count > 0:
        x2pi = uniform() * two_pi
        g2rad = sqrt(-2.0 * log(1.0 - uniform()))
        out.append(0.0 + cos(x2pi) * g2rad * 1.0)
        if count == 1:
            cache.gauss_next = sin(x2pi) * g2rad
            break
        out.append(0.0 + sin(x2pi) * g2rad * 1.0)
        count -= 2
    return out


class ObjectLoadCell:
    """A `LoadCell` sampling the world's tension through the emulator's `SignalModel`, without lines."""

    def __init__(
        self,
        tension_n: TensionSource,
        clock: VirtualClock,
        *,
        rate_hz: float,
        signal: SignalModel,
        seed: int,
        artefacts: ArtefactModel | None = None,
        tensions_n: Callable[[Sequence[int]], list[float]] | None = None,
    ) -> None:
        """`tensions_n`, if given, is `tension_n` over a batch of ascending times (`SimWorld.tensions_at`)."""
        if not MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ:
            raise LimitError(f"load-cell rate {rate_hz:g} Hz; allowed: {MIN_RATE_HZ:g}-{MAX_RATE_HZ:g}")
        self.tension_n = tension_n
        self.tensions_n = tensions_n
        self.clock = clock
        self.rate_hz = float(rate_hz)
        self.signal = signal
        self.artefacts = artefacts
        self.calibration = object_calibration(signal)
        self.start_ns = clock.monotonic_ns()
        self._rng = random.Random(seed)
        self._k = 0
        self._open = False
        self._pending: list[LoadCellSample] = []
        # The device samples from power-on whether or not anyone listens (the noise draws with it).
        clock.on_advance(self._sample_until)

    def _sample_until(self, now_ns: int) -> None:
        start, rate = self.start_ns, self.rate_hz
        k = self._k
        times: list[int] = []
        while True:
            t_ns = start + round(k * 1e9 / rate)
            if t_ns > now_ns:
                break
            times.append(t_ns)
            k += 1
        if not times:
            return
        self._k = k
        draws = gauss_draws(self._rng, len(times))  # one per sample, taken or not, as the emulator does
        artefacts = self.artefacts
        if not self._open and artefacts is None:
            return  # nobody listens and no artefact stream to advance: the draws were all that counts
        if self.tensions_n is not None:
            tensions = self.tensions_n(times)  # fast path: one batch lookup
        else:
            tension = self.tension_n
            tensions = [tension(t_ns) for t_ns in times]
        elapsed = [(t_ns - start) / 1e9 for t_ns in times]
        if artefacts is not None:  # as the emulator applies them, before the signal model
            period_s = 1.0 / rate
            tensions = [
                artefacts.apparent_tension_n(n, e, period_s) for n, e in zip(tensions, elapsed, strict=True)
            ]
        if not self._open:
            return
        counts = self.signal.counts_many(tensions, elapsed, draws)
        epoch_offset = self.clock.time_ns() - self.clock.monotonic_ns()
        offset, factor = self.calibration.offset_counts, self.calibration.factor_n_per_count
        # Calibration.force_n spelled out: (raw - offset) * factor; no seq or device time.
        self._pending.extend(
            LoadCellSample(t_ns + epoch_offset, c, (c - offset) * factor)
            for t_ns, c in zip(times, counts, strict=True)
        )

    def open(self) -> None:
        """Start receiving: samples taken before now were sent to a closed port and are lost."""
        self._sample_until(self.clock.monotonic_ns() - 1)
        self._open = True

    def poll(self) -> list[LoadCellSample]:
        """The samples taken since the last call."""
        out, self._pending = self._pending, []
        return out

    def close(self) -> None:
        """Stop receiving."""
        self._open = False
        self._pending = []
