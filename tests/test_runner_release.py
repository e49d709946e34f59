"""The release after a failure works from its own copy of the control loop's last reading."""

from __future__ import annotations

import dataclasses
from typing import Any, cast

import pytest

from rig.errors import BusWatchdogTripped
from rig.hw.dxl.bus import WatchdogTrip
from rig.hw.seams import LoadCellSample
from rig.hw.session import RigSession
from rig.inputs.protocol import RampSettings
from rig.inputs.rig_config import load_rig_config
from rig.log.format import schemas
from rig.runner.control_loop import ControlLoop
from rig.runner.recorder import RunRecorder
from rig.runner.sinks import NullSink
from rig.safety.interlocks import CurrentAtLimit, ForceCeiling
from rig.safety.release import LineRelease
from rig.sim.kinds import DeviceLevel
from rig.sim.simulated_rig import simulated_rig
from rig.testing.recording import RecordingServoBus

RAMP = RampSettings(
    fast_speed_rad_s=2.0,
    slow_speed_rad_s=0.5,
    fast_until_fraction=0.6,
    max_force_n=50.0,
    unload_speed_rad_s=2.0,
    hold_after_slip_s=0.2,
)


class _Log(NullSink):
    wants_ticks = True

    def __init__(self) -> None:
        self.messages: list[tuple[str, int, Any]] = []

    def log(self, topic: str, time_ns: int, payload: Any) -> None:
        self.messages.append((topic, time_ns, payload))

    def tick_rows(self, samples: Any, states: Any, roles: Any) -> None:
        self.messages.append(("ticks", 0, [list(samples), dict(states)]))


def _loop_on_a_simulated_rig() -> tuple[RigSession, ControlLoop, RunRecorder]:
    """The control loop on the object-level simulated rig (servo calls recorded), connected, one tick in."""
    rig = simulated_rig(load_rig_config(None), devices=DeviceLevel.OBJECT)
    session = dataclasses.replace(rig.session, servos=RecordingServoBus(rig.devices.bus))
    recorder = RunRecorder([_Log()], session.clock, session.roles)
    loop = ControlLoop(
        session,
        recorder,
        period_s=0.01,
        ceiling=ForceCeiling(100.0),
        current_limit=CurrentAtLimit(session.winch_id, 1.0, hold_s=1.0),
    )
    session.servos.connect()
    session.servos.set_torque([session.winch_id], True)
    session.load_cell.open()
    loop.restart_pacing()
    loop.tick()
    return session, loop, recorder


def test_release_waits_from_its_own_copy_and_leaves_the_loop_alone_until_adopted():
    session, loop, recorder = _loop_on_a_simulated_rig()
    winch = session.winch_id
    start_rad = loop.states[winch].position_rad
    zero_rad = start_rad - 1.0  # the ramp reeled in one radian
    release = LineRelease(session, recorder, RAMP, control_period_s=0.01, tare_n=0.0, last=loop.reading())
    # What a step or the ramp might do to the loop's readings after the release was made:
    loop.states = {}
    loop.tick_samples.append(LoadCellSample(0, 0, 1e6))
    loop.force_n = 1e6

    assert release.run(zero_rad) == zero_rad
    assert release.at_zero
    assert release.report[0] == "winch back at its zero-tension angle (read back)"
    assert abs(release.states[winch].position_rad - zero_rad) < 0.02
    # The loop saw none of the release's reads ...
    assert loop.states == {} and loop.force_n == 1e6
    # ... until it takes them over.
    loop.adopt(release.reading())
    assert loop.states[winch].position_rad == release.states[winch].position_rad
    assert loop.force_n == release.force_n


def test_release_reboots_a_faulted_winch_from_the_state_it_was_given():
    session, loop, recorder = _loop_on_a_simulated_rig()
    winch = session.winch_id
    last = loop.reading()
    faulted = dataclasses.replace(last.states[winch], hardware_error=0x20)
    last.states[winch] = faulted
    release = LineRelease(session, recorder, RAMP, control_period_s=0.01, tare_n=0.0, last=last)
    release.run(faulted.position_rad)
    assert release.report[0] == "winch rebooted after hardware error 0x20"
    # The servo had no error: only the given state said so.
    assert [c.args for c in cast(RecordingServoBus, session.servos).calls_to("reboot")] == [
        {"servo_id": winch}
    ]


class _PausedInTheRead:
    """The servo bus of a host stopped for 1.5 s while it read the states, which tripped the watchdog."""

    def __init__(self, inner: Any, clock: Any) -> None:
        self.inner, self.clock, self.paused = inner, clock, False

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def read_states(self) -> Any:
        states = self.inner.read_states()
        self.clock.sleep(1.5)
        self.paused = True
        return states

    def take_watchdog_trips(self) -> list[WatchdogTrip]:
        return [WatchdogTrip(1, "winch", 1.5)] if self.paused else []


def test_a_host_paused_inside_a_ticks_reads_is_a_late_tick_though_the_trip_ends_the_trial():
    """Found on the twin (a SIGSTOP landing in a bus read): the trip voided the trial before any tick
    started late, so the pause went unreported. The tick that finds the trip counts it."""
    session, loop, recorder = _loop_on_a_simulated_rig()
    loop.session = dataclasses.replace(session, servos=_PausedInTheRead(session.servos, session.clock))
    with pytest.raises(BusWatchdogTripped):
        loop.tick()
    log = cast(_Log, recorder.sinks[0])
    notes = [payload["message"] for topic, _, payload in log.messages if topic == schemas.LOG]
    assert any(n.startswith("control tick late by 1490.0 ms") for n in notes), notes
    assert loop.take_tick_stats().late_ticks == 1
