"""Motion models for an emulated Dynamixel: profile generation and a quasi-static geared motor.

Pure: `ProfiledActuator.step(state, command, dt_s, external_torque_nm)` returns the new state.
Everything is in SI at the **output shaft**, in the shaft's physical direction (the servo maps
register values, Drive Mode reverse, homing and multi-turn offsets onto it).

The model (documented choice, parameters in `MotorParams`):

* No inertia. The shaft velocity follows from a torque balance
  `motor_torque + external_torque = friction(velocity)`, with gear friction
  `coulomb_nm * sign(v) + viscous_nm_s * v` while driven, a static band `|net| <= coulomb_nm` in which
  the shaft sticks, and the motor's speed-torque slope `stall_torque / no_load_speed` as the damping
  when the shaft is back-driven (the motor acts as a brake, as a shorted DC motor does).
* Motor torque = torque constant x current; the current is capped by the mode's limit
  (Current Limit, or Goal Current in mode 5). A position/velocity controller asks for the velocity
  `ref_velocity + position_gain * (ref_position - position)`; when the torque this needs exceeds the
  cap the motor saturates: it advances slower, **stalls** while the load stays within the friction
  band of the cap, and is **back-driven** when the load exceeds the cap by more than the band.
* While holding still and unsaturated, the motor exactly balances the load (Present Current =
  -external torque / torque constant), so current reads back the line tension's torque.
* Profiles: an online trapezoid from the Profile Velocity/Acceleration (0 = unlimited, velocity
  capped by the Velocity Limit), replanned from the current reference when a goal changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

POSITION_MODES = frozenset({3, 4, 5})


@dataclass(frozen=True, slots=True)
class MotorParams:
    """Output-shaft motor and gear constants (defaults scaled from the datasheet stall point)."""

    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rad_s: float
    coulomb_fraction: float = 0.04  # gear Coulomb friction and back-drive threshold, fraction of stall torque
    viscous_fraction: float = 0.02  # gear viscous friction at no-load speed, fraction of stall torque
    position_gain_per_s: float = 30.0  # position-loop bandwidth of the emulated controller

    @property
    def torque_constant_nm_per_a(self) -> float:
        """Output torque per ampere."""
        return self.stall_torque_nm / self.stall_current_a

    @property
    def coulomb_nm(self) -> float:
        """Coulomb friction torque (and the static band)."""
        return self.coulomb_fraction * self.stall_torque_nm

    @property
    def viscous_nm_s(self) -> float:
        """Viscous gear friction per rad/s."""
        return self.viscous_fraction * self.stall_torque_nm / self.no_load_speed_rad_s

    @property
    def backdrive_nm_s(self) -> float:
        """Damping while back-driven: the motor's speed-torque slope."""
        return self.stall_torque_nm / self.no_load_speed_rad_s


@dataclass(frozen=True, slots=True)
class ActuatorCommand:
    """What the servo's registers ask for, converted to physical output-shaft units."""

    torque_enabled: bool = False
    mode: int = 3
    goal_position_rad: float = 0.0
    goal_velocity_rad_s: float = 0.0
    goal_torque_nm: float = 0.0  # mode 0 (current control)
    pwm_fraction: float = 0.0  # mode 16, -1..1
    torque_limit_nm: float = 0.0  # cap on |motor torque| (Current Limit, or Goal Current in mode 5)
    profile_velocity_rad_s: float = math.inf  # already capped by the Velocity Limit
    profile_acceleration_rad_s2: float = math.inf  # inf = unlimited


@dataclass(slots=True)
class ActuatorState:
    """The shaft and the profile reference."""

    position_rad: float = 0.0
    velocity_rad_s: float = 0.0
    motor_torque_nm: float = 0.0
    ref_position_rad: float = 0.0
    ref_velocity_rad_s: float = 0.0
    saturated: bool = False  # the motor torque is at its cap (time at the cap feeds overload detection)
    profile_done: bool = True


def _sign(x: float) -> float:
    return 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)


def profile_step(
    ref_rad: float, ref_v: float, goal_rad: float, v_max: float, a_max: float, dt_s: float
) -> tuple[float, float, bool]:
    """One step of an online trapezoidal profile; returns (position, velocity, reached)."""
    d = goal_rad - ref_rad
    if math.isinf(a_max):
        # max(-v_max, min(v_max, d / dt_s)) spelled out with the builtins' exact tie and NaN rules
        # (min keeps its first argument unless a later one is smaller); this runs every millisecond.
        v = d / dt_s
        v = v if v < v_max else v_max
        v = v if v > -v_max else -v_max
        new = ref_rad + v * dt_s
        if abs(goal_rad - new) < 1e-12:
            return goal_rad, 0.0, True
        return new, v, False
    if abs(d) < 1e-12 and abs(ref_v) <= a_max * dt_s:
        return goal_rad, 0.0, True
    v_stop = math.sqrt(2.0 * a_max * abs(d))
    v_target = _sign(d) * min(v_max, v_stop)
    dv = a_max * dt_s
    v = min(v_target, ref_v + dv) if v_target > ref_v else max(v_target, ref_v - dv)
    new = ref_rad + 0.5 * (ref_v + v) * dt_s
    # Arrive exactly instead of oscillating around the goal.
    if (goal_rad - new) * d <= 0.0 and abs(v) <= 2.0 * dv + 1e-12:
        return goal_rad, 0.0, True
    return new, v, False


class ProfiledActuator:
    """Profile generator + saturating quasi-static motor (see the module docstring)."""

    def __init__(self, params: MotorParams) -> None:
        self.params = params

    @property
    def params(self) -> MotorParams:
        """The motor constants (setting them refreshes the derived constants the steps use)."""
        return self._params

    @params.setter
    def params(self, params: MotorParams) -> None:
        self._params = params
        # MotorParams is frozen; its derived properties are evaluated once here, not on every step.
        self._stall_nm = params.stall_torque_nm
        self._no_load = params.no_load_speed_rad_s
        self._gain = params.position_gain_per_s
        self._coulomb = params.coulomb_nm
        self._viscous = params.viscous_nm_s
        self._backdrive = params.backdrive_nm_s

    def step(
        self, state: ActuatorState, cmd: ActuatorCommand, dt_s: float, external_torque_nm: float
    ) -> ActuatorState:
        """Advance `state` by `dt_s` under `cmd` and a constant external torque; returns `state`."""
        tau_ext = external_torque_nm
        if not cmd.torque_enabled:
            state.motor_torque_nm = 0.0
            state.velocity_rad_s = self._passive_velocity(tau_ext, self._backdrive)
            state.position_rad += state.velocity_rad_s * dt_s
            state.ref_position_rad, state.ref_velocity_rad_s = state.position_rad, 0.0
            state.saturated, state.profile_done = False, True
            return state
        mode = cmd.mode
        if mode == 0:
            tau_m = max(-cmd.torque_limit_nm, min(cmd.torque_limit_nm, cmd.goal_torque_nm))
            self._apply_open_loop(state, tau_m, tau_ext, dt_s)
            state.saturated = (
                abs(tau_m) >= cmd.torque_limit_nm > 0 and abs(cmd.goal_torque_nm) >= cmd.torque_limit_nm
            )
            return state
        if mode == 16:
            # Voltage control: the motor's speed-torque line scaled by the PWM duty.
            tau_m = cmd.pwm_fraction * self._stall_nm
            self._apply_open_loop(state, tau_m, tau_ext, dt_s, line=True)
            state.saturated = False
            return state
        no_load = self._no_load
        v_cap = cmd.profile_velocity_rad_s
        v_cap = v_cap if v_cap < no_load else no_load  # min(no_load, profile velocity)
        if mode == 1:
            goal_v = max(-v_cap, min(v_cap, cmd.goal_velocity_rad_s))
            a = cmd.profile_acceleration_rad_s2
            dv = math.inf if math.isinf(a) else a * dt_s
            rv = state.ref_velocity_rad_s
            rv = min(goal_v, rv + dv) if goal_v > rv else max(goal_v, rv - dv)
            state.ref_velocity_rad_s = rv
            state.profile_done = rv == goal_v
            desired = rv
        else:
            # Error against the reference *before* this step, so that steps of any length converge.
            ref = state.ref_position_rad
            err = ref - state.position_rad
            if not state.profile_done or ref != cmd.goal_position_rad:
                ref, rv, done = profile_step(
                    ref,
                    state.ref_velocity_rad_s,
                    cmd.goal_position_rad,
                    v_cap,
                    cmd.profile_acceleration_rad_s2,
                    dt_s,
                )
                state.ref_position_rad, state.ref_velocity_rad_s, state.profile_done = ref, rv, done
            desired = state.ref_velocity_rad_s + self._gain * err
            # max(-no_load, min(no_load, desired)), spelled out as in profile_step.
            desired = desired if desired < no_load else no_load
            desired = desired if desired > -no_load else -no_load
            if state.profile_done and abs(ref - state.position_rad) < 1e-4 and not state.saturated:
                # Settled: hold exactly at the reference, balancing the load.
                desired = 0.0
                state.position_rad = ref
        self._track(state, desired, cmd.torque_limit_nm, tau_ext, dt_s)
        if mode == 1:
            state.ref_position_rad = state.position_rad
        return state

    def _passive_velocity(self, net_nm: float, damping: float) -> float:
        c = self._coulomb
        if abs(net_nm) <= c:
            return 0.0
        v = (net_nm - _sign(net_nm) * c) / damping
        limit = 2.0 * self._no_load
        return max(-limit, min(limit, v))

    def _apply_open_loop(
        self, state: ActuatorState, tau_m: float, tau_ext: float, dt_s: float, line: bool = False
    ) -> None:
        net = tau_m + tau_ext
        # Driven by the motor: gear friction (plus the motor line in PWM mode); else back-driven.
        damping = self._viscous + (self._backdrive if line else 0.0)
        if _sign(net) != _sign(tau_m):
            damping = self._backdrive
        v = self._passive_velocity(net, damping)
        if line:
            tau_m -= self._backdrive * v  # back-EMF: torque falls with speed at a fixed duty
        state.motor_torque_nm = tau_m
        state.velocity_rad_s = v
        state.position_rad += v * dt_s
        state.ref_position_rad, state.ref_velocity_rad_s = state.position_rad, v

    def _track(
        self, state: ActuatorState, desired: float, limit_nm: float, tau_ext: float, dt_s: float
    ) -> None:
        stall = self._stall_nm
        limit_nm = stall if stall < limit_nm else limit_nm  # min(limit_nm, stall torque)
        if desired == 0.0:
            needed = -tau_ext
        else:
            sign = 1.0 if desired > 0 else (-1.0 if desired < 0 else 0.0)  # _sign(desired), inlined
            needed = self._viscous * desired + self._coulomb * sign - tau_ext
        if abs(needed) <= limit_nm:
            state.motor_torque_nm = needed
            state.velocity_rad_s = desired
            state.saturated = False
        else:
            tau_m = _sign(needed) * limit_nm
            net = tau_m + tau_ext
            damping = self._viscous if _sign(net) == _sign(tau_m) else self._backdrive
            state.motor_torque_nm = tau_m
            state.velocity_rad_s = self._passive_velocity(net, damping)
            state.saturated = True
        state.position_rad += state.velocity_rad_s * dt_s
