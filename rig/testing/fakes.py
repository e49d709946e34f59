"""Object-level fakes of the hardware seams for tests: no bytes, no emulators, no world, fast.

Test doubles only (`rig.testing` is imported by no rig module; pyproject.toml's import contract).
The simulated rig's own object-level devices are `rig.sim.object_devices` (the same world as the
byte-level rig); these fakes are simpler and scriptable (recorded calls, injected errors, a line
with given slip forces) for the runner's tests.

In the spirit of ophyd-async's mock backends, these implement the `rig.hw.seams` Protocols
directly, on a shared `Clock` (a `VirtualClock` in tests):

* `FakeServoBus` (`ServoBus`): servos move to their goals with first-order motion (time constant
  `time_constant_s`), capped at the profile velocity, only while torque is on and no hardware error
  is latched. Hardware errors can be injected per servo (now or at a given time; like a Dynamixel,
  a latched error drops the torque); `silent = True` makes every call raise `CommunicationError`.
  Every call is recorded in `calls`, in order, including the steps of `shutdown`.
* `FakeLoadCell` (`LoadCell`): samples a tension function of time at `rate_hz` on the clock; it can be
  silenced for a time window, and then `poll` raises `StaleDataError` once no sample has arrived
  for longer than `stale_timeout_s`, as `rig.hw.loadcell.driver.SerialLoadCell` does; after
  `disconnect()` (cable pulled) `poll` raises `NotConnectedError`, as the driver does when reading fails.
  It is a `LineStatsSource` too: samples due during a silence are counted as missing (their `seq`
  is skipped, as a device's counter would be); no line is ever garbled.
* `FakeLine`: the world between them: tension = stiffness x (winch angle - line zero), never
  negative; at each of the given slip forces the link gives and the tension drops by a fraction.
* `fake_rig`: a `RigSession` built from them, with an operator that confirms at once (or raises
  KeyboardInterrupt at a chosen trial) and a manual bending fixture.

Where a test needs no scripted slip forces, injected errors or a silent bus, it uses the
object-level simulated rig (`rig.sim.object_rig`) instead, with `rig.testing.recording.RecordingServoBus`
to see the servo calls: tests/test_manual_bending.py and tests/test_runner_release.py do.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

from rig.errors import CommunicationError, HardwareFault, NotConnectedError, StaleDataError
from rig.hw.bending import ManualBending
from rig.hw.seams import Clock, LoadCellLineStats, LoadCellSample, OperatingMode, ServoState
from rig.hw.session import RigSession
from rig.protocol import TrialPlan
from rig.sim.clock import VirtualClock
from rig.vocabulary import RigKind, ServoRole

MOVING_THRESHOLD_RAD_S = 0.02  # |velocity| above this sets the `moving` flag
_SEGMENTS_KEPT = 64  # motion history per servo, for states asked at past times


class FakeCall(NamedTuple):
    """One recorded call on a fake: clock time (monotonic ns), method name, arguments."""

    time_ns: int
    name: str
    args: dict[str, Any]


@dataclass(frozen=True, slots=True)
class _Segment:
    """Motion from `start_ns` on, until the next segment: first order toward a fixed goal."""

    start_ns: int
    position_rad: float
    goal_rad: float
    speed_cap_rad_s: float  # inf: no profile velocity
    driven: bool  # torque on and no hardware error


def _move(seg: _Segment, dt_s: float, tau_s: float) -> tuple[float, float]:
    """Position and velocity `dt_s` into a segment (exact for dp/dt = clip((goal - p) / tau, +-cap))."""
    if not seg.driven:
        return seg.position_rad, 0.0
    error = seg.goal_rad - seg.position_rad
    sign = 1.0 if error >= 0 else -1.0
    left = abs(error)
    cap = seg.speed_cap_rad_s
    if left > cap * tau_s:  # saturated: constant speed until the error is cap * tau
        reach_s = (left - cap * tau_s) / cap
        if dt_s <= reach_s:
            return seg.position_rad + sign * cap * dt_s, sign * cap
        dt_s -= reach_s
        left = cap * tau_s
    left *= math.exp(-max(dt_s, 0.0) / tau_s)
    return seg.goal_rad - sign * left, sign * left / tau_s


@dataclass
class FakeServo:
    """One fake servo: settings as last written, latched error, and its motion history."""

    servo_id: int
    mode: OperatingMode = OperatingMode.EXTENDED_POSITION
    torque_enabled: bool = False
    hardware_error: int = 0
    goal_rad: float = 0.0
    profile_velocity_rad_s: float = 0.0  # 0: unlimited
    profile_acceleration_rad_s2: float = 0.0
    goal_current_a: float | None = None
    current_limit_a: float | None = None
    current_a: float = 0.0  # what read_states reports; tests may set it
    reboots: int = 0
    torque_wanted: bool = False  # what the host last asked for; a reboot restores it, as the driver does
    segments: list[_Segment] = field(default_factory=list)
    pending_errors: list[tuple[int, int]] = field(default_factory=list)  # (at monotonic ns, bits)

    def segment_at(self, t_ns: int) -> _Segment:
        """The motion segment in force at `t_ns` (the first one for earlier times)."""
        for seg in reversed(self.segments):
            if seg.start_ns <= t_ns:
                return seg
        return self.segments[0]


class FakeServoBus:
    """A `ServoBus` of fake servos on a clock; see the module docstring."""

    def __init__(
        self,
        clock: Clock,
        servo_ids: Iterable[int] = (1,),
        *,
        positions_rad: Mapping[int, float] | None = None,
        time_constant_s: float = 0.05,
    ) -> None:
        if time_constant_s <= 0:
            raise ValueError(f"time_constant_s: {time_constant_s}; allowed: > 0")
        self.clock = clock
        self.time_constant_s = time_constant_s
        self.silent = False  # True: every call raises CommunicationError
        self.calls: list[FakeCall] = []
        self.connected = False
        self.closed = False
        self._shut_down = False
        now = clock.monotonic_ns()
        positions = dict(positions_rad or {})
        self.servos: dict[int, FakeServo] = {}
        for sid in servo_ids:
            p0 = float(positions.get(sid, 0.0))
            self.servos[sid] = FakeServo(sid, goal_rad=p0, segments=[_Segment(now, p0, p0, math.inf, False)])

    # -- inspection and fault injection (not part of the seam) --------------------------------------

    def servo(self, servo_id: int) -> FakeServo:
        """The fake servo with this ID (KeyError if it is not on the bus)."""
        return self.servos[servo_id]

    def motion_at(self, servo_id: int, t_ns: int) -> tuple[float, float, bool]:
        """(position, velocity, driven) of a servo at monotonic `t_ns` (up to now)."""
        self._apply_pending_errors()
        servo = self.servos[servo_id]
        seg = servo.segment_at(t_ns)
        position, velocity = _move(seg, (t_ns - seg.start_ns) / 1e9, self.time_constant_s)
        return position, velocity, seg.driven

    def position_rad(self, servo_id: int) -> float:
        """Present position of a servo."""
        return self.motion_at(servo_id, self.clock.monotonic_ns())[0]

    def inject_hardware_error(self, servo_id: int, bits: int = 0x20, *, at_ns: int | None = None) -> None:
        """Latch Hardware Error Status `bits` (0x20: overload) now or at monotonic `at_ns`; torque drops."""
        if bits <= 0:
            raise ValueError(f"hardware error bits: {bits}; allowed: > 0")
        now = self.clock.monotonic_ns()
        self.servos[servo_id].pending_errors.append((now if at_ns is None else max(at_ns, now), bits))
        self._apply_pending_errors()

    def calls_to(self, name: str) -> list[FakeCall]:
        """The recorded calls of one method, in order."""
        return [c for c in self.calls if c.name == name]

    def call_names(self, *, reads: bool = False) -> list[str]:
        """The names of the recorded calls in order (without `read_states` unless `reads`)."""
        return [c.name for c in self.calls if reads or c.name != "read_states"]

    # -- the ServoBus seam --------------------------------------------------------------------------

    def connect(self) -> None:
        """Connect (records the call; raises CommunicationError when silent)."""
        self._call("connect", {}, connected=False)
        self.connected = True
        self.closed = False

    def read_states(self) -> dict[int, ServoState]:
        """The state of every servo now."""
        self._call("read_states", {})
        now = self.clock.monotonic_ns()
        time_ns = self.clock.time_ns()
        states = {}
        for sid, servo in self.servos.items():
            position, velocity, _ = self.motion_at(sid, now)
            states[sid] = ServoState(
                servo_id=sid,
                position_rad=position,
                velocity_rad_s=velocity,
                current_a=servo.current_a,
                hardware_error=servo.hardware_error,
                moving=abs(velocity) > MOVING_THRESHOLD_RAD_S,
                time_ns=time_ns,
            )
        return states

    def set_operating_mode(
        self,
        servo_id: int,
        mode: OperatingMode,
        *,
        goal_current_a: float | None = None,
        profile_velocity_rad_s: float | None = None,
        profile_acceleration_rad_s2: float | None = None,
    ) -> None:
        """Switch mode; the goal becomes the present position (no jump); torque ends as it was."""
        self._call(
            "set_operating_mode",
            {
                "servo_id": servo_id,
                "mode": OperatingMode(mode),
                "goal_current_a": goal_current_a,
                "profile_velocity_rad_s": profile_velocity_rad_s,
                "profile_acceleration_rad_s2": profile_acceleration_rad_s2,
            },
        )
        servo = self._servo(servo_id)
        servo.mode = OperatingMode(mode)
        if goal_current_a is not None:
            servo.goal_current_a = goal_current_a
        if profile_velocity_rad_s is not None:
            servo.profile_velocity_rad_s = profile_velocity_rad_s
        if profile_acceleration_rad_s2 is not None:
            servo.profile_acceleration_rad_s2 = profile_acceleration_rad_s2
        servo.goal_rad = self.position_rad(servo_id)
        self._rebase(servo)

    def set_torque(self, servo_ids: Sequence[int], enabled: bool) -> None:
        """Torque on or off; enabling a servo with a latched hardware error raises HardwareFault."""
        self._call("set_torque", {"servo_ids": list(servo_ids), "enabled": enabled})
        for sid in servo_ids:
            servo = self._servo(sid)
            if enabled and servo.hardware_error:
                raise HardwareFault(f"servo {sid}: hardware error 0x{servo.hardware_error:02x} is latched")
            servo.torque_enabled = servo.torque_wanted = enabled
            self._rebase(servo)

    def set_profile(
        self, servo_id: int, velocity_rad_s: float | None = None, acceleration_rad_s2: float | None = None
    ) -> None:
        """Profile velocity (caps the speed; 0 = unlimited) and acceleration (recorded only)."""
        self._call(
            "set_profile",
            {
                "servo_id": servo_id,
                "velocity_rad_s": velocity_rad_s,
                "acceleration_rad_s2": acceleration_rad_s2,
            },
        )
        servo = self._servo(servo_id)
        if velocity_rad_s is not None:
            servo.profile_velocity_rad_s = velocity_rad_s
        if acceleration_rad_s2 is not None:
            servo.profile_acceleration_rad_s2 = acceleration_rad_s2
        self._rebase(servo)

    def set_current_limit(self, servo_id: int, current_limit_a: float) -> None:
        """Record the current limit."""
        self._call("set_current_limit", {"servo_id": servo_id, "current_limit_a": current_limit_a})
        self._servo(servo_id).current_limit_a = current_limit_a

    def write_goal_positions(self, goals_rad: Mapping[int, float]) -> None:
        """New goals; each servo heads there from where it is now."""
        self._call("write_goal_positions", {"goals_rad": dict(goals_rad)})
        servos = [self._servo(sid) for sid in goals_rad]
        for servo in servos:
            servo.goal_rad = float(goals_rad[servo.servo_id])
            self._rebase(servo)

    def write_goal_currents(self, goals_a: Mapping[int, float]) -> None:
        """Record the goal currents."""
        self._call("write_goal_currents", {"goals_a": dict(goals_a)})
        for sid, current in goals_a.items():
            self._servo(sid).goal_current_a = current

    def reboot(self, servo_id: int) -> None:
        """Clear the latched hardware error; torque is restored as it was wanted."""
        self._call("reboot", {"servo_id": servo_id})
        servo = self._servo(servo_id)
        servo.hardware_error = 0
        servo.reboots += 1
        servo.goal_rad = self.position_rad(servo_id)
        servo.torque_enabled = servo.torque_wanted
        self._rebase(servo)

    def shutdown(self, release: Callable[[], None] | None = None) -> None:
        """Run `release`, then torque off every servo, then close; re-raise the first error.

        Like the real driver: idempotent, every step is tried whatever failed before, and a
        KeyboardInterrupt from `release` is re-raised only after the torque is off.
        """
        if self._shut_down:
            return
        self._shut_down = True
        self.calls.append(FakeCall(self.clock.monotonic_ns(), "shutdown", {"release": release is not None}))
        errors: list[BaseException] = []
        if release is not None:
            try:
                release()
            except BaseException as exc:
                errors.append(exc)
        ids = list(self.servos)
        self.calls.append(FakeCall(self.clock.monotonic_ns(), "torque_off", {"servo_ids": ids}))
        if self.silent:
            errors.append(CommunicationError(f"servos {ids}: no reply to torque off"))
        elif self.connected:
            for servo in self.servos.values():
                servo.torque_enabled = False
                self._rebase(servo)
        self.calls.append(FakeCall(self.clock.monotonic_ns(), "close", {}))
        self.connected = False
        self.closed = True
        if errors:
            first = errors[0]
            for other in errors[1:]:
                first.add_note(f"also during servo shutdown: {type(other).__name__}: {other}")
            raise first

    # -- internals -----------------------------------------------------------------------------------

    def _call(self, name: str, args: dict[str, Any], *, connected: bool = True) -> None:
        self.calls.append(FakeCall(self.clock.monotonic_ns(), name, args))
        if self.silent:
            raise CommunicationError(f"fake servo bus: no reply to {name}")
        if connected and not self.connected:
            state = "shut down" if self._shut_down else "not connected"
            raise NotConnectedError(f"fake servo bus is {state}")
        self._apply_pending_errors()

    def _servo(self, servo_id: int) -> FakeServo:
        try:
            return self.servos[servo_id]
        except KeyError:
            raise NotConnectedError(
                f"servo {servo_id} is not on the fake bus {sorted(self.servos)}"
            ) from None

    def _rebase(self, servo: FakeServo, at_ns: int | None = None) -> None:
        """Start a new motion segment at `at_ns` (now) from where the servo is then."""
        t_ns = self.clock.monotonic_ns() if at_ns is None else at_ns
        seg = servo.segment_at(t_ns)
        position, _ = _move(seg, (t_ns - seg.start_ns) / 1e9, self.time_constant_s)
        cap = servo.profile_velocity_rad_s if servo.profile_velocity_rad_s > 0 else math.inf
        driven = servo.torque_enabled and not servo.hardware_error
        servo.segments.append(_Segment(t_ns, position, servo.goal_rad, cap, driven))
        del servo.segments[:-_SEGMENTS_KEPT]

    def _apply_pending_errors(self) -> None:
        now = self.clock.monotonic_ns()
        for servo in self.servos.values():
            due = sorted(e for e in servo.pending_errors if e[0] <= now)
            for at_ns, bits in due:
                servo.pending_errors.remove((at_ns, bits))
                servo.hardware_error |= bits
                servo.torque_enabled = False  # a latched error drops the torque
                self._rebase(servo, at_ns)


class FakeLoadCell:
    """A `LoadCell` sampling `tension(t_ns)` (monotonic ns -> N) at `rate_hz`; see the module docstring."""

    def __init__(
        self,
        clock: Clock,
        tension: Callable[[int], float],
        *,
        rate_hz: float = 1000.0,
        stale_timeout_s: float = 0.5,
        counts_per_n: float = 1000.0,
        name: str = "fake-loadcell",
    ) -> None:
        if not (rate_hz > 0 and stale_timeout_s > 0):
            raise ValueError("rate_hz and stale_timeout_s must be > 0")
        self.clock = clock
        self.tension = tension
        self.period_ns = round(1e9 / rate_hz)
        self.stale_timeout_s = stale_timeout_s
        self.counts_per_n = counts_per_n
        self.name = name
        self.calls: list[FakeCall] = []
        self.silences: list[tuple[int, int]] = []  # [start, end) monotonic ns without samples
        self.samples_sent = 0
        self._open = False
        self._anchor_ns = 0
        self._next_ns = 0
        self._seq = 0
        self._last_valid_ns = 0
        self._failure: str | None = None
        self._line_stats = LoadCellLineStats(0, 0, 0, 0, 0, 0)
        self._in_gap = False

    @property
    def is_open(self) -> bool:
        """Between `open()` and `close()`."""
        return self._open

    def line_stats(self) -> LoadCellLineStats:
        """Samples sent and missed (silences) since `open()`."""
        return self._line_stats

    def silence(self, duration_s: float = math.inf, *, at_ns: int | None = None) -> None:
        """Send nothing for `duration_s` from monotonic `at_ns` (default: now), as if unplugged."""
        start = self.clock.monotonic_ns() if at_ns is None else at_ns
        end = start + round(duration_s * 1e9) if math.isfinite(duration_s) else 2**63
        self.silences.append((start, end))

    def disconnect(self, reason: str = "device disconnected") -> None:
        """From now on `poll` raises NotConnectedError (the port failed), until the next `open`."""
        self._failure = reason

    def open(self) -> None:
        """Start sampling now; staleness counts from here."""
        self.calls.append(FakeCall(self.clock.monotonic_ns(), "open", {}))
        now = self.clock.monotonic_ns()
        self._open = True
        self._failure = None
        self._anchor_ns = self.clock.time_ns() - now
        self._next_ns = now + self.period_ns
        self._last_valid_ns = now
        self._line_stats = LoadCellLineStats(0, 0, 0, 0, 0, 0)
        self._in_gap = False

    def poll(self) -> list[LoadCellSample]:
        """The samples due since the last call; StaleDataError when silent for too long."""
        if not self._open:
            raise NotConnectedError(f"load cell {self.name}: not open")
        if self._failure is not None:
            raise NotConnectedError(f"load cell {self.name}: reading failed: {self._failure}")
        now = self.clock.monotonic_ns()
        samples: list[LoadCellSample] = []
        missing = gaps = 0
        while self._next_ns <= now:
            t_ns = self._next_ns
            self._next_ns += self.period_ns
            self._seq += 1
            if any(start <= t_ns < end for start, end in self.silences):
                missing += 1
                if not self._in_gap:
                    gaps += 1
                    self._in_gap = True
                continue
            self._in_gap = False
            force = float(self.tension(t_ns))
            samples.append(
                LoadCellSample(self._anchor_ns + t_ns, round(force * self.counts_per_n), force, self._seq)
            )
            self._last_valid_ns = t_ns
        self.samples_sent += len(samples)
        if samples or missing:
            stats = self._line_stats
            self._line_stats = replace(
                stats,
                lines_ok=stats.lines_ok + len(samples),
                missing_samples=stats.missing_samples + missing,
                sequence_gaps=stats.sequence_gaps + gaps,
            )
        if samples:
            return samples
        age_s = (now - self._last_valid_ns) / 1e9
        if age_s > self.stale_timeout_s:
            raise StaleDataError(
                f"load cell {self.name}: no valid sample for {age_s:.3f} s; limit {self.stale_timeout_s:g} s"
            )
        return samples

    def close(self) -> None:
        """Stop sampling (idempotent)."""
        self.calls.append(FakeCall(self.clock.monotonic_ns(), "close", {}))
        self._open = False


@dataclass(frozen=True)
class Slip:
    """A slip of the fake link: when, at what tension, and the tension right after."""

    time_ns: int
    force_n: float
    force_after_n: float


class FakeLine:
    """The line from the winch to the link: tension from the winch angle, slips at given forces.

    tension = stiffness x (winch angle - line zero), never negative. When it reaches the next of
    `slip_forces_n`, the link gives: the line zero moves so that the tension drops by
    `drop_fraction`; the slip after it can happen only once the line was unloaded below
    `rearm_below_n` (one slip per loading). A winch without torque (off, or a latched error) is
    back-driven by the line and holds no tension. Ask in time order (the load cell does).
    """

    def __init__(
        self,
        servos: FakeServoBus,
        winch_id: int = 1,
        *,
        stiffness_n_per_rad: float = 50.0,
        zero_rad: float = 0.0,
        slip_forces_n: Sequence[float] = (),
        drop_fraction: float = 0.4,
        rearm_below_n: float = 1.0,
    ) -> None:
        if not 0 < drop_fraction < 1:
            raise ValueError(f"drop_fraction: {drop_fraction}; allowed: (0, 1)")
        self.servos = servos
        self.winch_id = winch_id
        self.stiffness_n_per_rad = stiffness_n_per_rad
        self.zero_rad = zero_rad
        self.slip_forces_n = list(slip_forces_n)
        self.drop_fraction = drop_fraction
        self.rearm_below_n = rearm_below_n
        self.slips: list[Slip] = []
        self._armed = True

    def tension_at(self, t_ns: int) -> float:
        """The line tension at monotonic `t_ns` [N]; applies a slip when its force is reached."""
        position, _, driven = self.servos.motion_at(self.winch_id, t_ns)
        if not driven:
            return 0.0
        force = max(0.0, self.stiffness_n_per_rad * (position - self.zero_rad))
        if force < self.rearm_below_n:
            self._armed = True
        next_slip = len(self.slips)
        if self._armed and next_slip < len(self.slip_forces_n) and force >= self.slip_forces_n[next_slip]:
            after = force * (1.0 - self.drop_fraction)
            self.zero_rad += (force - after) / self.stiffness_n_per_rad
            self.slips.append(Slip(t_ns, force, after))
            self._armed = False
            force = after
        return force


class FakeOperator:
    """Confirms every prompt at once and records it; raises KeyboardInterrupt at `interrupt_at_trial`."""

    def __init__(self, interrupt_at_trial: int | None = None) -> None:
        self.interrupt_at_trial = interrupt_at_trial
        self.prompts: list[tuple[int | None, str]] = []

    def confirm(self, text: str, trial: TrialPlan | None, keep_alive: Callable[[], None]) -> None:
        """Record the prompt; Ctrl-C if this is the trial to interrupt."""
        trial_id = trial.trial_id if trial is not None else None
        self.prompts.append((trial_id, text))
        if trial_id is not None and trial_id == self.interrupt_at_trial:
            raise KeyboardInterrupt


@dataclass
class FakeRig:
    """A fake rig: one winch on a line to a link that slips, a load cell, an operator, the session."""

    clock: VirtualClock
    servos: FakeServoBus
    load_cell: FakeLoadCell
    line: FakeLine
    operator: FakeOperator
    session: RigSession

    @property
    def winch(self) -> FakeServo:
        """The winch servo."""
        return self.servos.servo(self.session.winch_id)


def fake_rig(
    *,
    winch_id: int = 1,
    stiffness_n_per_rad: float = 50.0,
    slip_forces_n: Sequence[float] = (),
    drop_fraction: float = 0.4,
    rate_hz: float = 1000.0,
    stale_timeout_s: float = 0.2,
    time_constant_s: float = 0.05,
    interrupt_at_trial: int | None = None,
) -> FakeRig:
    """A fake rig on a fresh `VirtualClock` (one winch, no benders), ready for `execute_run`."""
    clock = VirtualClock()
    servos = FakeServoBus(clock, [winch_id], time_constant_s=time_constant_s)
    line = FakeLine(
        servos,
        winch_id,
        stiffness_n_per_rad=stiffness_n_per_rad,
        slip_forces_n=slip_forces_n,
        drop_fraction=drop_fraction,
    )
    load_cell = FakeLoadCell(clock, line.tension_at, rate_hz=rate_hz, stale_timeout_s=stale_timeout_s)
    operator = FakeOperator(interrupt_at_trial)
    session = RigSession(
        kind=RigKind.SIMULATED,
        clock=clock,
        servos=servos,
        load_cell=load_cell,
        operator=operator,
        fixture=ManualBending(),
        configuration=None,
        winch_id=winch_id,
        roles={winch_id: ServoRole.WINCH},
    )
    return FakeRig(clock, servos, load_cell, line, operator, session)
