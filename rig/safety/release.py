"""The release of the line when something failed: the winch back to its zero-tension angle, whatever broke.

It runs in the safe state that ends every run (`rig.safety.safe_state.enter_safe_state`, before
torque goes off) and after a device fault inside a trial. It keeps its own state: it starts from
a copy of what the control loop saw last and reads the rig itself from then on, so nothing a step
or the ramp does to the loop's readings can change what it sees or waits for. `reading()` hands
its last readings back to the loop when it ends.

Each stage goes on when an earlier one failed, and what was verified is recorded in `report`: a
winch with a latched hardware error is rebooted first (its turn count is lost, so the zero is
carried over into the new count); the goal goes out as a broadcast sync write, which needs no
reply; the wait reads the winch's position back, for twice its travel time at the speed in force
and `margin_s` (`servos.release_margin_s`) more. A bus that stops answering (a USB adapter that
hangs) is given `patience_s` (`servos.release_patience_s`) per silence: when it answers again the
goal goes out again (a servo whose Bus Watchdog tripped in the silence refused the first one; the
driver has cleared the trip by then) and the wait goes on. A bus silent for longer, or a port that
vanished, ends the wait unverified, with what is known of the winch in `report`. The load cell is
optional: it may be what failed.
"""

from __future__ import annotations

import contextlib
import math

from rig.errors import NotConnectedError, RigError, StepTimeoutError
from rig.hw.seams import LoadCellSample, WatchdogTripSource
from rig.hw.session import RigSession
from rig.inputs.protocol import RampSettings
from rig.inputs.rig_config import DEFAULT_RELEASE_MARGIN_S, DEFAULT_SLACK_SETTLE_S
from rig.records import LogLevel, ServoCommandName
from rig.runner.control_loop import Reading, tare_corrected
from rig.runner.recorder import RunRecorder
from rig.safety.safe_state import POSITION_TOLERANCE_RAD, move_timeout_s


class LineRelease:
    """One release of the line, from the readings it was given; see the module docstring."""

    def __init__(
        self,
        session: RigSession,
        recorder: RunRecorder,
        ramp: RampSettings,
        *,
        control_period_s: float,
        tare_n: float,
        last: Reading,
        patience_s: float = 0.0,
        margin_s: float = DEFAULT_RELEASE_MARGIN_S,
        settle_s: float = DEFAULT_SLACK_SETTLE_S,
        port: str = "the servo port",
    ) -> None:
        self.session = session
        self.clock = session.clock
        self.recorder = recorder
        self.ramp = ramp
        self.control_period_s = control_period_s
        self.tare_n = tare_n
        self.states = dict(last.states)
        self.tick_samples = list(last.tick_samples)
        self.force_n = last.force_n
        self._cell_answered = bool(last.tick_samples)  # any sample in the release (or the tick before)
        self.patience_s = patience_s
        self.margin_s = margin_s
        self.settle_s = settle_s
        self.port = port
        self.report: list[str] = []  # what the release did and verified
        self.at_zero = False  # the winch's position was read back at its zero-tension angle
        self.slack_confirmed = False  # ... and the load cell read the line slack there (or is gone, said)
        self.tension_measured = True  # False: the cell gave no reading once the winch was back

    def reading(self) -> Reading:
        """What the release read last."""
        return Reading(self.states, self.tick_samples, self.force_n)

    def run(self, zero_rad: float) -> float:
        """Back the winch off to `zero_rad`; its zero-tension angle in its (possibly new) turn count.

        StepTimeoutError if the winch answers but does not get there in time.
        """
        winch = self.session.winch_id
        servos = self.session.servos
        report = self.report
        zero_rad = self._recover_winch(zero_rad)
        speed = self.ramp.unload_speed_rad_s
        try:
            servos.set_profile(winch, velocity_rad_s=speed)
        except RigError as exc:
            # The profile in force is one the ramp set: wait as long as the slowest would take.
            speed = min(speed, self.ramp.slow_speed_rad_s, self.ramp.fast_speed_rad_s)
            report.append(f"release speed not confirmed ({exc})")
        self._send_goal(zero_rad)
        last = self.states.get(winch)
        travel = abs(last.position_rad - zero_rad) if last is not None else 2 * math.pi
        wait_s = move_timeout_s(travel, speed, self.margin_s)
        clock = self.clock
        deadline = clock.monotonic_ns() + round(wait_s * 1e9)
        silent_since: int | None = None  # when the bus stopped answering (None: it answers)
        while True:
            now = clock.monotonic_ns()
            if silent_since is None and now >= deadline:
                break
            try:
                self._tick_without_interlocks()
            except NotConnectedError:  # the port itself failed: no point in waiting
                report.append(
                    f"the servo port {self.port} is gone: the release was not confirmed (not verified)"
                )
                return zero_rad
            except RigError:
                now = clock.monotonic_ns()
                silent_since = now if silent_since is None else silent_since
                if now - silent_since >= self.patience_s * 1e9 and now >= deadline:
                    report.append(self._silent_bus_report(zero_rad, (now - silent_since) / 1e9))
                    return zero_rad
                clock.sleep(self.control_period_s)  # not answering: keep trying
                continue
            if silent_since is not None or self._watchdog_tripped():
                # The bus is back: a goal sent into the silence, or refused by a tripped watchdog,
                # goes out again, and the winch gets the travel time from where it is now.
                quiet_s = (clock.monotonic_ns() - silent_since) / 1e9 if silent_since is not None else 0.0
                if silent_since is not None:
                    report.append(f"the servo bus was silent for {quiet_s:.1f} s and answered again")
                silent_since = None
                with contextlib.suppress(RigError):  # the speed may not have been set in the silence
                    servos.set_profile(winch, velocity_rad_s=speed)
                self._send_goal(zero_rad)
                travel = abs(self.states[winch].position_rad - zero_rad)
                deadline = clock.monotonic_ns() + round(move_timeout_s(travel, speed, self.margin_s) * 1e9)
            if abs(self.states[winch].position_rad - zero_rad) < POSITION_TOLERANCE_RAD:
                self.at_zero = True
                report.append("winch back at its zero-tension angle (read back)")
                return zero_rad
        raise StepTimeoutError("winch did not return to zero tension within its timeout")

    def confirm_slack(self, tolerance_n: float) -> bool:
        """With the winch at its zero: does the load cell read the line slack? Recorded in `report`.

        Waits up to `settle_s` (`loadcell.slack_settle_s`) for a sample within `tolerance_n` of the
        cell's zero (tare corrected), taken at or after the winch's arrival. A cell that gives no
        sample at all in the release is gone: the release is taken on the winch's position alone, and
        the report says the tension was not measured. A cell reading beyond the tolerance is not
        slack: not verified.
        """
        if not self.at_zero:
            return False
        deadline = self.clock.monotonic_ns() + round(self.settle_s * 1e9)
        fresh = bool(self.tick_samples)  # the arrival's tick brought a sample
        while not (fresh and abs(self.force_n) <= tolerance_n):
            if self.clock.monotonic_ns() >= deadline:
                break
            try:
                self._tick_without_interlocks()
            except RigError:
                break  # the servo bus stopped answering: the cell's last word stands
            fresh = fresh or bool(self.tick_samples)
        if not fresh:
            self.slack_confirmed = True
            self.tension_measured = False
            last = f" (it last read {self.force_n:+.2f} N)" if self._cell_answered else ""
            self.report.append(
                f"the load cell gave no reading once the winch was back{last}: the tension was not measured"
            )
        elif abs(self.force_n) <= tolerance_n:
            self.slack_confirmed = True
            self.report.append(
                f"tension {self.force_n:+.2f} N (load cell, within limits.zero_tolerance_n {tolerance_n:g} N)"
            )
        else:
            self.report.append(
                f"the load cell reads {self.force_n:+.2f} N with the winch at its zero-tension angle, beyond "
                f"limits.zero_tolerance_n ({tolerance_n:g} N): the line may still be loaded (a winch turned "
                "the wrong way, a line wound round the drum the other way) or the cell's zero moved "
                "(not verified)"
            )
        return self.slack_confirmed

    def _send_goal(self, zero_rad: float) -> None:
        """The zero-tension goal by broadcast (no reply needed); a port that fails is reported, not raised."""
        winch = self.session.winch_id
        try:
            self.session.servos.write_goal_positions({winch: zero_rad})
        except NotConnectedError:
            self.report.append(f"zero-tension goal not sent (the servo port {self.port} failed)")
            return
        self.recorder.command(winch, ServoCommandName.GOAL_POSITION, zero_rad, "rad")

    def _watchdog_tripped(self) -> bool:
        """Whether the driver found (and cleared) a Bus Watchdog trip on this read; logged."""
        servos = self.session.servos
        if not isinstance(servos, WatchdogTripSource):
            return False
        trips = servos.take_watchdog_trips()
        for trip in trips:
            self.recorder.note(LogLevel.WARNING, trip.describe())
            self.report.append(trip.describe())
        return bool(trips)

    def _silent_bus_report(self, zero_rad: float, silent_s: float) -> str:
        """What is known of the winch when the bus stayed silent beyond the patience (for the report)."""
        last = self.states.get(self.session.winch_id)
        where = f"{last.position_rad - zero_rad:+.2f} rad from its zero-tension angle" if last else "unknown"
        tension = f"; the load cell last read {self.force_n:+.2f} N" if self.tick_samples else ""
        return (
            f"the winch has not answered on the servo bus {self.port} for {silent_s:.1f} s "
            f"(servos.release_patience_s {self.patience_s:g} s): it was last read {where}{tension}; its "
            "zero-tension goal went "
            "out by broadcast but was not confirmed, and if the servos did not hear it their Bus Watchdog "
            "holds the winch where it was, torque on (not verified). Check the servo adapter's USB cable "
            "and the servos' power supply"
        )

    def _recover_winch(self, zero_rad: float) -> float:
        """Reboot a winch whose hardware error dropped its torque; the zero-tension angle after it.

        A reboot folds the multi-turn position into one turn, and the shaft does not move while
        its torque is off, so the turns lost are the difference of the positions before and after.
        """
        winch = self.session.winch_id
        state = self.states.get(winch)
        if state is None or not state.hardware_error:
            return zero_rad
        servos = self.session.servos
        servos.reboot(winch)
        self.states = servos.read_states()
        turns = round((state.position_rad - self.states[winch].position_rad) / (2 * math.pi))
        self.report.append(f"winch rebooted after hardware error 0x{state.hardware_error:02X}")
        return zero_rad - turns * 2 * math.pi

    def _tick_without_interlocks(self) -> None:
        """One control period of the release: read the servos and log; the load cell is optional.

        The load cell may be what failed (stale, unplugged, a port error): the release goes on
        without it, since only the winch's position is waited for.
        """
        self.clock.sleep(self.control_period_s)
        self.states = self.session.servos.read_states()
        samples: list[LoadCellSample]
        try:
            samples = self.session.load_cell.poll()
        except Exception:  # whatever the load cell's failure, the line still has to be released
            samples = []
        self.tick_samples = tare_corrected(samples, self.tare_n)
        if samples:
            self.force_n = self.tick_samples[-1].force_n
            self._cell_answered = True
        self.recorder.tick_rows(self.tick_samples, self.states)
