"""The seam wrappers of `rig.testing` (injected errors, recorded prompts) on the object-level simulated rig,
and what the runner tests rely on of the object-level devices themselves."""

from __future__ import annotations

import pytest

from rig.errors import CommunicationError, StaleDataError
from rig.hw.dxl.control_table import RAD_PER_PULSE
from rig.hw.seams import LoadCell, OperatingMode, ServoBus
from rig.hw.session import OperatorRequest, OperatorTask
from rig.inputs.protocol import TrialPlan
from rig.inputs.rig_config import load_rig_config
from rig.sim.kinds import DeviceLevel
from rig.sim.simulated_rig import simulated_rig
from rig.testing.injected_errors import ErrorInjector
from rig.testing.prompts import RecordingOperator
from rig.vocabulary import TrialKind


@pytest.fixture
def sim():
    """The built-in simulated rig on object-level devices, bus connected, winch (servo 1) torque on."""
    rig = simulated_rig(load_rig_config(None), seed=0, devices=DeviceLevel.OBJECT)
    rig.devices.bus.connect()
    rig.devices.bus.set_operating_mode(1, OperatingMode.CURRENT_BASED_POSITION, profile_velocity_rad_s=1.0)
    rig.devices.bus.set_torque([1], True)
    return rig


def test_the_object_level_devices_implement_the_seams(sim):
    assert isinstance(sim.devices.bus, ServoBus) and isinstance(sim.session.load_cell, LoadCell)
    assert sim.session.roles == {1: "winch", 2: "bender"} and sim.session.winch_id == 1


def test_an_error_on_the_nth_call_fires_once_and_the_failed_call_does_not_reach_the_bus(sim):
    bus = ErrorInjector(sim.devices.bus)
    bus.write_goal_positions({1: 0.1})  # counted before the error was armed
    bus.raise_on_call("write_goal_positions", CommunicationError("servo 1: no reply"), nth=2)
    bus.write_goal_positions({1: 0.2})
    with pytest.raises(CommunicationError, match="no reply"):
        bus.write_goal_positions({1: 5.0})
    assert sim.devices.bus.servo(1).goal_pulses * RAD_PER_PULSE == pytest.approx(0.2, abs=RAD_PER_PULSE)
    bus.write_goal_positions({1: 0.3})  # once only
    assert bus.calls["write_goal_positions"] == 4
    assert bus.read_states()[1].servo_id == 1  # other methods, and attributes, are the bus's
    assert bus.servos is sim.devices.bus.servos
    with pytest.raises(ValueError, match="not a public method"):
        bus.raise_on_call("no_such_method", CommunicationError("x"))


def test_errors_while_the_flag_is_set_are_fresh_each_time_and_stop_with_it(sim):
    cell = ErrorInjector(sim.session.load_cell)
    cell.open()
    cell.raise_while(StaleDataError("no valid sample for 0.2 s"), methods={"poll"})
    raised = []
    for _ in range(2):
        with pytest.raises(StaleDataError, match="no valid sample") as caught:
            cell.poll()
        caught.value.add_note("the runner's note")
        raised.append(caught.value)
    assert raised[0] is not raised[1] and raised[1].__notes__ == ["the runner's note"]
    cell.close()  # not among the failing methods
    cell.stop_raising()
    cell.open()
    sim.session.clock.sleep(0.01)
    assert cell.poll()  # samples again
    bus = ErrorInjector(sim.devices.bus)
    bus.raise_while(CommunicationError("cable pulled"))  # every method
    for call in (bus.read_states, lambda: bus.set_torque([1], False), bus.shutdown):
        with pytest.raises(CommunicationError, match="cable pulled"):
            call()
    assert sim.devices.bus.servo(1).torque_enabled  # nothing reached the servos


def test_the_object_bus_shutdown_releases_then_turns_the_torque_off_and_re_raises_ctrl_c(sim):
    torque_at_release = []

    def release() -> None:
        torque_at_release.append(sim.devices.bus.servo(1).torque_enabled)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sim.devices.bus.shutdown(release)
    assert torque_at_release == [True]
    assert not any(servo.torque_enabled for servo in sim.devices.bus.servos)


def test_the_recording_operator_passes_prompts_on_and_interrupts_at_its_trial():
    class Person:
        def __init__(self) -> None:
            self.confirmed: list[str] = []

        def confirm(self, request, keep_alive) -> None:
            self.confirmed.append(request.text)

    person = Person()
    seen = []
    operator = RecordingOperator(person, interrupt_at_trial=2, on_prompt=seen.append)
    trials = [TrialPlan(i, 0, TrialKind.JOINT_ESTIMATION, 1, (), joint=1, distance_m=0.1) for i in (1, 2)]

    def prompt(text: str, trial: TrialPlan | None) -> OperatorRequest:
        return OperatorRequest(OperatorTask.FOLLOW_PROMPT, text, trial)

    operator.confirm(prompt("connect the line", None), lambda: None)
    operator.confirm(prompt("hook at 0.1 m", trials[0]), lambda: None)
    with pytest.raises(KeyboardInterrupt):
        operator.confirm(prompt("hook at 0.1 m", trials[1]), lambda: None)
    assert operator.prompts == [(None, "connect the line"), (1, "hook at 0.1 m"), (2, "hook at 0.1 m")]
    assert person.confirmed == ["connect the line", "hook at 0.1 m"]  # the Ctrl-C was not passed on
    assert seen == [None, *trials]
