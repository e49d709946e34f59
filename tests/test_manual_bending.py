"""Bending by hand: the benders give way while the operator sets the link, then hold it as left."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from rig.runner.progress import SilentProgress
from rig.runner.run import RunRequest, execute_run, prepare_run
from rig.sim.clock import VirtualClock
from rig.testing.fakes import FakeLine, FakeLoadCell, FakeOperator, FakeServoBus, fake_session
from rig.vocabulary import TrialOutcome

PROTOCOL = """\
format: rig-protocol/1
name: by-hand
detector: {arm_threshold_n: 2.0, drop_fraction: 0.15}
ramp: {fast_speed_rad_s: 1.0, slow_speed_rad_s: 0.3, max_force_n: 70.0}
limits: {force_ceiling_n: 75.0}
blocks:
  - kind: joint_estimation
    joint: 1
    distances_m: [0.12, 0.2]
    repeats: 1
    steps: [{tare: {settle_s: 0.1}}, ramp_until_slip, unload]
  - kind: link_validation
    estimates_from: run
    configurations_deg: [[5, 5, 5, 5, -5, -5, -5, -5]]
    steps: [bend, {tare: {settle_s: 0.1}}, ramp_until_slip, unload, reset]
"""


class TorqueWatchingOperator(FakeOperator):
    """Records, at each prompt, whether the bender's torque is on, then moves the bender as a hand would."""

    def __init__(self, servos: FakeServoBus, bender: int) -> None:
        super().__init__()
        self.servos = servos
        self.bender = bender
        self.torque_at_prompt: list[bool] = []

    def confirm(self, text, trial, keep_alive: Callable[[], None]) -> None:  # type: ignore[no-untyped-def]
        super().confirm(text, trial, keep_alive)
        self.torque_at_prompt.append(self.servos.servo(self.bender).torque_enabled)


def test_benders_are_off_while_the_operator_bends(protocol_file: Callable[..., Path], tmp_path: Path) -> None:
    clock = VirtualClock()
    servos = FakeServoBus(clock, [1, 2], time_constant_s=0.05)
    line = FakeLine(servos, 1, stiffness_n_per_rad=50.0, slip_forces_n=[20.0, 15.0, 30.0], drop_fraction=0.4)
    load_cell = FakeLoadCell(clock, line.tension_at, rate_hz=1000.0, stale_timeout_s=0.2)
    operator = TorqueWatchingOperator(servos, bender=2)
    session = fake_session(clock, servos, load_cell, winch_id=1, operator=operator)
    request = RunRequest(protocol_path=protocol_file(PROTOCOL), rig_path=None, out_dir=tmp_path, seed=0)
    report = execute_run(prepare_run(request), session, SilentProgress())
    assert report.exit_code == 0, report.reason
    assert [t.outcome for t in report.trials] == [TrialOutcome.SLIP] * 3
    assert operator.torque_at_prompt == [False, False]  # given way for the bend and the reset by hand
    torque_calls = [c.args for c in servos.calls_to("set_torque") if 2 in c.args["servo_ids"]]
    # on at connect; off for each hand, on again to hold (the run's shutdown turns it off at the end)
    assert [c["enabled"] for c in torque_calls] == [True, False, True, False, True]
    assert not servos.servo(2).torque_enabled
    goals = [c.args["goals_rad"] for c in servos.calls_to("write_goal_positions") if 2 in c.args["goals_rad"]]
    assert goals, "the bender's goal is set to where the hand left it before its torque comes back"
