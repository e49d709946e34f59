"""Bending by hand: the benders give way while the operator sets the link, then hold it as left."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from rig.hw.bending import ManualBending
from rig.hw.session import OperatorTask
from rig.inputs.rig_config import load_rig_config
from rig.runner.execute import RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress
from rig.sim.kinds import DeviceLevel
from rig.sim.object_devices import ObjectServoBus
from rig.sim.simulated_rig import SimulatedPerson, simulated_rig
from rig.testing.recording import RecordingServoBus
from rig.vocabulary import TrialOutcome
from tests.helpers import quick_then_link_validation

PROTOCOL = quick_then_link_validation(
    "by-hand",
    configurations_deg=[[5, 5, 5, 5, -5, -5, -5, -5]],
    steps=["bend", {"tare": {"settle_s": 0.1}}, "ramp_until_slip", "unload", "reset"],
)


class TorqueWatchingOperator(SimulatedPerson):
    """Records, at each request, whether the bender's torque is on (the simulated person then bends)."""

    def __init__(self, person: SimulatedPerson, servos: ObjectServoBus, bender: int) -> None:
        super().__init__(person.world)
        self.servos = servos
        self.bender = bender
        self.torque_at_prompt: list[bool] = []

    def confirm(self, request, keep_alive: Callable[[], None]) -> None:  # type: ignore[no-untyped-def]
        super().confirm(request, keep_alive)
        if request.task is not OperatorTask.FOLLOW_PROMPT:  # a request to set the link by hand
            self.torque_at_prompt.append(self.servos.servo(self.bender).torque_enabled)


def test_benders_are_off_while_the_operator_bends(protocol_file: Callable[..., Path], tmp_path: Path) -> None:
    config = load_rig_config(None)  # the default simulated rig: no forks, the link is bent by hand
    rig = simulated_rig(config, devices=DeviceLevel.OBJECT)
    assert isinstance(rig.session.fixture, ManualBending)
    winch, bender = config.servos.winch.servo_id, config.servos.benders[0].servo_id
    bus = rig.devices.bus
    servos = RecordingServoBus(bus)
    operator = TorqueWatchingOperator(rig.person, bus, bender)
    session = dataclasses.replace(rig.session, servos=servos, operator=operator)
    request = RunRequest(protocol_path=protocol_file(PROTOCOL), rig_path=None, out_dir=tmp_path, seed=0)
    report = execute_run(prepare_run(request), dataclasses.replace(rig, session=session), SilentProgress())
    assert report.exit_code == 0, report.reason
    assert [t.outcome for t in report.trials] == [TrialOutcome.SLIP] * 3
    assert operator.torque_at_prompt == [False, False]  # given way for the bend and the reset by hand
    torque_calls = [c.args for c in servos.calls_to("set_torque") if bender in c.args["servo_ids"]]
    # on at connect; off for each hand, on again to hold (the run's shutdown turns it off at the end)
    assert [c["enabled"] for c in torque_calls] == [True, False, True, False, True]
    assert not bus.servo(bender).torque_enabled and not bus.servo(winch).torque_enabled
    goals = [
        c.args["goals_rad"] for c in servos.calls_to("write_goal_positions") if bender in c.args["goals_rad"]
    ]
    assert goals, "the bender's goal is set to where the hand left it before its torque comes back"
