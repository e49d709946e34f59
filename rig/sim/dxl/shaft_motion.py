"""The motion integration both simulated servos share: the emulated one (bytes) and the object-level one.

`IntegratedShaft._integrate(now_ns)` steps the profiled actuator (`actuator.py`) up to `now_ns` in
substeps of at most `MAX_STEP_NS`, under the external torque the world set, with the overload
latch (the motor at its cap for `overload_time_ns` latches Overload Error via `_on_overload`), and
two shortcuts that keep a run cheap without changing a single step: *idle* (torque off, no motion,
the load within the gear's static friction) and *settled* (holding still under the same command and
load, a fixed point of the quasi-static step: the bender idles most of a run). One definition, so the
two device levels integrate exactly the same steps for the same seed.
"""

from __future__ import annotations

from rig.sim.dxl.actuator import ActuatorCommand, ActuatorState, ProfiledActuator

MAX_STEP_NS = 1_000_000  # motion integration sub-step


class IntegratedShaft:
    """Mixin: the attributes below are the servo's; `_on_overload` latches the error (may change `_cmd`)."""

    actuator: ProfiledActuator
    state: ActuatorState
    external_torque_nm: float
    overload_time_ns: int
    _cmd: ActuatorCommand
    _now_ns: int
    _at_limit_ns: int
    _coulomb_nm: float
    _overload_cap_nm: float
    _settled: tuple[ActuatorCommand, float, float] | None

    def _on_overload(self) -> None:
        """Latch Overload Error (the motor held its cap for `overload_time_ns`)."""
        raise NotImplementedError

    def _at_rest(self) -> bool:
        """True if `_integrate` would take the idle or the settled shortcut (under this external torque).

        Either shortcut moves nothing: one `_integrate` to a later time leaves the very state that
        any number of them in between would (the world skips a still stretch on this).
        """
        return self._shortcut() is not None

    def _shortcut(self) -> str | None:
        """The stretch `_integrate` may skip without stepping the actuator: "idle", "settled" or None."""
        state, cmd, tau_ext = self.state, self._cmd, self.external_torque_nm
        if not cmd.torque_enabled and state.velocity_rad_s == 0.0 and abs(tau_ext) <= self._coulomb_nm:
            return "idle"  # torque off and the load inside the gear's static friction band
        settled = self._settled
        if (
            settled is not None
            and settled[0] is cmd
            and settled[1] == tau_ext
            and settled[2] == state.position_rad
        ):
            return "settled"  # holding still under an unchanged load and command
        return None

    def _integrate(self, now_ns: int) -> None:
        t = self._now_ns
        if now_ns <= t:
            return
        shortcut = self._shortcut()
        if shortcut is not None:
            if shortcut == "idle":  # zero motor torque and overload timer, the same each time
                self.state.motor_torque_nm = 0.0
                self._at_limit_ns = 0
            self._now_ns = now_ns  # integrating would change nothing
            return
        state, cmd = self.state, self._cmd
        tau_ext = self.external_torque_nm
        step = self.actuator.step
        overload_cap_nm = self._overload_cap_nm
        while t < now_ns:
            dt_ns = now_ns - t
            if dt_ns > MAX_STEP_NS:
                dt_ns = MAX_STEP_NS
            step(state, cmd, dt_ns * 1e-9, tau_ext)
            t += dt_ns
            if cmd.torque_enabled and abs(state.motor_torque_nm) >= overload_cap_nm > 0:
                self._at_limit_ns += dt_ns
                if self._at_limit_ns >= self.overload_time_ns:
                    self._now_ns = t  # the error is latched at this substep's time
                    self._on_overload()
                    cmd = self._cmd
                    self._at_limit_ns = 0
            else:
                self._at_limit_ns = 0
        self._now_ns = now_ns
        if (
            state.velocity_rad_s == 0.0
            and state.profile_done
            and not state.saturated
            and self._at_limit_ns == 0
        ):
            self._settled = (cmd, tau_ext, state.position_rad)
        else:
            self._settled = None
