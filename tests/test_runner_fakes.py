"""The runner on object-level fakes (rig/testing/fakes.py): what it commands, in what order, and how it ends.

Through the public API `prepare_run` / `execute_run`, with a session built from the fakes: no
bytes, no emulators. The byte-level simulated rig (tests/test_runner.py) stays the end-to-end path.
"""

from __future__ import annotations

import numpy as np
import pytest

from model.chain import planar_transforms
from rig.analysis.replay import replay
from rig.hw.seams import ConfigurationReading
from rig.runner.journal import RunJournal
from rig.runner.progress import SilentProgress
from rig.runner.ramp import RAMP_GOAL_LEAD_S
from rig.runner.run import RunRequest, execute_run, prepare_run
from rig.testing.fakes import FakeRig, fake_rig
from tests.helpers import QUICK_PROTOCOL

G = 9.8
CAPACITY_NM = 2.4  # the fake link slips at F = capacity / distance
DISTANCES_M = (0.12, 0.2, 0.25)
SLIP_FORCES_N = [CAPACITY_NM / d for d in DISTANCES_M]  # 20, 12, 9.6 N


@pytest.fixture
def run_on_fakes(tmp_path, protocol_file):
    """`run_on_fakes(rig)` -> RunReport: the protocol above on the fake rig, as `rig run` would run it."""
    protocol = protocol_file(QUICK_PROTOCOL)

    def run(rig: FakeRig):
        request = RunRequest(
            protocol_path=protocol, rig_path=None, out_dir=tmp_path / "out", seed=1, run_id="f1"
        )
        return execute_run(prepare_run(request), rig.session, SilentProgress())

    return run


def when_tension_reaches(rig: FakeRig, force_n: float, action) -> None:
    """Call `action(t_ns)` once, at the first load-cell sample with at least `force_n` on the line."""
    tension = rig.load_cell.tension
    fired = []

    def watched(t_ns: int) -> float:
        force = tension(t_ns)
        if force >= force_n and not fired:
            fired.append(t_ns)
            action(t_ns)
        return force

    rig.load_cell.tension = watched


def assert_released_then_torque_off(rig: FakeRig, zero_rad: float = 0.0) -> None:
    """Once the shutdown began: the winch sent back to its zero, then torque off; it ends there, slack."""
    calls = [c for c in rig.servos.calls if c.name != "read_states"]
    names = [c.name for c in calls]
    start = names.index("shutdown")
    release = [
        i
        for i, c in enumerate(calls)
        if i > start and c.name == "write_goal_positions" and c.args["goals_rad"] == {1: zero_rad}
    ]
    assert release, names[start:]
    assert release[0] < names.index("torque_off"), names[start:]
    assert names[-2:] == ["torque_off", "close"]
    assert not rig.winch.torque_enabled and rig.servos.closed and not rig.load_cell.is_open
    # Back at zero within the runner's position tolerance (0.02 rad): at most 1 N left on the line.
    assert rig.servos.position_rad(1) == pytest.approx(zero_rad, abs=0.02)
    assert rig.line.stiffness_n_per_rad * (rig.servos.position_rad(1) - rig.line.zero_rad) < 1.0


def journal_status(tmp_path) -> str:
    return RunJournal.load(tmp_path / "out" / "f1.journal.json").status


# ------------------------------------------------------------------------------------------ slips


def test_slips_give_outcome_slip_and_the_estimate_follows(run_on_fakes):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    report = run_on_fakes(rig)
    assert report.exit_code == 0 and report.completed == 3 and not report.aborted
    assert [t.outcome for t in report.trials] == ["slip"] * 3
    assert [s.force_n for s in rig.line.slips] == pytest.approx(SLIP_FORCES_N, abs=0.05)
    for trial, force in zip(report.trials, SLIP_FORCES_N, strict=True):
        assert trial.peak_force_n == pytest.approx(force, abs=0.05)  # 1 kHz at 15 N/s: 0.015 N a sample
    # Trial 1 has no prediction; trial 3 is planned from the fit of trials 1 and 2, which is exact here.
    assert report.trials[0].predicted_mass_kg is None
    third = report.trials[2]
    assert third.predicted_mass_kg == pytest.approx(third.slip_mass_kg, rel=0.01)
    assert report.estimate.n == 3
    assert report.estimate.k == pytest.approx(CAPACITY_NM / G, rel=0.01)
    # Each trial: tare, reel in (fast, then slow from the arm threshold), hold after the slip, unload.
    goals = [c.args["goals_rad"][1] for c in rig.servos.calls_to("write_goal_positions")]
    assert goals.count(0.0) == 3 + 1  # one unload per trial, and the release at the end
    assert rig.operator.prompts and [t for t, _ in rig.operator.prompts] == [1, 2, 3]
    assert_released_then_torque_off(rig)


def test_connect_sets_up_the_winch_before_torque_on(run_on_fakes):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    run_on_fakes(rig)
    names = rig.servos.call_names()
    assert names[:4] == ["connect", "set_current_limit", "set_operating_mode", "set_torque"]
    mode = rig.servos.calls_to("set_operating_mode")[0].args
    assert (
        mode["mode"] == 5
        and mode["goal_current_a"] == rig.servos.calls_to("set_current_limit")[0].args["current_limit_a"]
    )
    assert rig.servos.calls_to("set_torque")[0].args == {"servo_ids": [1], "enabled": True}
    assert [c.name for c in rig.load_cell.calls] == ["open", "close"]


# ------------------------------------------------------------------------------------------ faults


def test_stale_load_cell_during_the_ramp_stops_released_then_torque_off(run_on_fakes, tmp_path):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    unplugged = []

    def unplug(t_ns: int) -> None:
        unplugged.append(rig.servos.position_rad(1))
        rig.load_cell.silence(at_ns=t_ns + 1)

    when_tension_reaches(rig, 5.0, unplug)
    report = run_on_fakes(rig)
    assert report.exit_code == 1 and report.aborted and report.completed == 0
    assert "StaleDataError" in report.reason and "no valid sample" in report.reason
    assert journal_status(tmp_path) == "faulted"
    assert unplugged and unplugged[0] > 0.05  # the line was loaded when the data stopped
    assert rig.line.slips == []
    assert_released_then_torque_off(rig)


def test_hardware_error_on_the_winch_reboots_it_releases_the_line_and_repeats_the_trial(
    run_on_fakes, tmp_path
):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    when_tension_reaches(rig, 5.0, lambda t_ns: rig.servos.inject_hardware_error(1, 0x20))
    report = run_on_fakes(rig)
    # The fault dropped the torque with the line loaded: the winch is rebooted and unwinds; the rig
    # answers healthily again, so the trial is repeated and the run completes.
    assert report.exit_code == 0 and report.completed == 3, report.reason
    assert report.safe_state_verified
    journal = RunJournal.load(tmp_path / "out" / "f1.journal.json")
    assert journal.status == "completed" and journal.retried_trials == [1]
    names = rig.servos.call_names()
    assert names.count("reboot") == 1 and names.index("reboot") < names.index("shutdown")
    assert_released_then_torque_off(rig)
    assert not rig.winch.torque_enabled and rig.winch.hardware_error == 0
    assert rig.servos.closed and not rig.load_cell.is_open


def test_servo_bus_going_silent_still_attempts_torque_off(run_on_fakes, tmp_path):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)

    def cable_pulled(t_ns: int) -> None:
        rig.servos.silent = True

    when_tension_reaches(rig, 5.0, cable_pulled)
    report = run_on_fakes(rig)
    assert report.exit_code == 1 and report.completed == 0
    assert "CommunicationError" in report.reason
    assert journal_status(tmp_path) == "faulted"
    names = rig.servos.call_names()
    assert names[-2:] == ["torque_off", "close"] and "shutdown" in names
    assert not rig.load_cell.is_open


# ------------------------------------------------------------------------------------------ Ctrl-C


def test_ctrl_c_at_the_operator_prompt_exits_130_released_then_torque_off(run_on_fakes, tmp_path):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    rig.operator.interrupt_at_trial = 2
    report = run_on_fakes(rig)
    assert report.exit_code == 130 and report.aborted and report.completed == 1
    assert report.reason == "interrupted by the operator"
    assert journal_status(tmp_path) == "interrupted"
    assert_released_then_torque_off(rig)


def test_ctrl_c_during_the_ramp_exits_130_released_then_torque_off(run_on_fakes, tmp_path):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    loaded = []

    def ctrl_c(t_ns: int) -> None:
        loaded.append(rig.servos.position_rad(1))
        raise KeyboardInterrupt  # as a SIGINT arriving in the middle of a control tick

    when_tension_reaches(rig, 8.0, ctrl_c)
    report = run_on_fakes(rig)
    assert report.exit_code == 130 and report.completed == 0
    assert journal_status(tmp_path) == "interrupted"
    assert loaded[0] == pytest.approx(8.0 / rig.line.stiffness_n_per_rad, abs=0.01)
    assert_released_then_torque_off(rig)


# ------------------------------------------------------------------- runner bugs these fakes found


def test_load_cell_cable_pulled_during_the_ramp_still_releases_before_torque_off(run_on_fakes, tmp_path):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    when_tension_reaches(rig, 8.0, lambda t_ns: rig.load_cell.disconnect("cable pulled"))
    report = run_on_fakes(rig)
    assert report.exit_code == 1 and "NotConnectedError" in report.reason
    assert journal_status(tmp_path) == "faulted"
    assert_released_then_torque_off(rig)


def test_a_failed_safe_state_after_a_fault_is_in_the_report(run_on_fakes):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    when_tension_reaches(rig, 5.0, lambda t_ns: setattr(rig.servos, "silent", True))
    report = run_on_fakes(rig)
    assert report.exit_code == 1 and "CommunicationError" in report.reason
    assert "torque off failed" in report.reason


def test_the_ramp_goal_stays_a_short_way_ahead_of_the_winch(run_on_fakes):
    # A host that dies mid-ramp must leave a winch that stops within a short lead, not one reeling on
    # to the end of its travel (20 turns here).
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    report = run_on_fakes(rig)
    assert report.exit_code == 0
    fast_lead = 1.0 * RAMP_GOAL_LEAD_S  # the protocol's fast speed, rad/s
    for call in rig.servos.calls_to("write_goal_positions"):
        goal = call.args["goals_rad"][1]
        position = rig.servos.motion_at(1, call.time_ns)[0]
        assert goal - position <= fast_lead + 1e-9, (call.time_ns, goal, position)


# ------------------------------------------------------------------- odd slips and step timeouts


def slides_at(rig: FakeRig, force_n: float, *, during_trials: set[int] | None = None) -> list[float]:
    """The link gives way at `force_n` without a drop (no slip to detect) in the trials named.

    Returns a list that gets the line tension at the start of every trial (at its prompt).
    """
    tension = rig.load_cell.tension
    current: list[int] = [0]
    at_prompt: list[float] = []

    def capped(t_ns: int) -> float:
        force = tension(t_ns)
        if force > force_n and (during_trials is None or current[0] in during_trials):
            rig.line.zero_rad += (force - force_n) / rig.line.stiffness_n_per_rad  # the link gives way
            return force_n
        return force

    confirm = rig.operator.confirm

    def confirm_and_note(text, trial, keep_alive):
        current[0] = trial.trial_id
        at_prompt.append(capped(rig.clock.monotonic_ns()))
        confirm(text, trial, keep_alive)

    rig.load_cell.tension = capped
    rig.operator.confirm = confirm_and_note  # type: ignore[method-assign]
    return at_prompt


def test_a_ramp_that_times_out_with_the_line_loaded_aborts_the_trial_and_the_run_goes_on(
    run_on_fakes, tmp_path
):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N[1:])  # trials 2 and 3 slip at their forces
    at_prompt = slides_at(rig, 8.0, during_trials={1})
    report = run_on_fakes(rig)
    assert report.exit_code == 0 and report.completed == 3 and not report.aborted, report.reason
    first, *others = report.trials
    assert first.outcome == "aborted" and "ramp_until_slip exceeded its timeout" in first.reason
    assert first.peak_force_n == pytest.approx(8.0, abs=0.05)  # the line was loaded when it timed out
    assert not first.slipped
    assert [t.outcome for t in others] == ["slip", "slip"] and all(t.reason is None for t in others)
    # The line was released before the next trial: slack at its start, and at the end of the run.
    assert at_prompt[1] < 0.5
    assert report.estimate.n == 2  # the aborted trial is not in the fit
    journal = RunJournal.load(tmp_path / "out" / "f1.journal.json")
    assert journal.status == "completed" and journal.completed[0].outcome == "aborted"
    assert journal.completed[0].reason == first.reason
    assert_released_then_torque_off(rig)


def test_a_run_whose_every_trial_times_out_ends_cleanly(run_on_fakes, tmp_path):
    rig = fake_rig(slip_forces_n=())
    at_prompt = slides_at(rig, 8.0)
    report = run_on_fakes(rig)
    # Every trial done, but nothing measured: the run fails (exit 1) saying so and why.
    assert report.exit_code == 1 and report.completed == 3 and report.aborted
    assert (report.reason or "").startswith("no trial gave a usable slip (3 aborted of 3): every trial")
    assert [t.outcome for t in report.trials] == ["aborted"] * 3
    assert all(p < 0.5 for p in at_prompt)
    assert report.estimate is None or report.estimate.n == 0
    assert journal_status(tmp_path) == "completed"
    assert_released_then_torque_off(rig)


def test_a_step_timeout_whose_release_fails_ends_the_run(run_on_fakes, tmp_path):
    rig = fake_rig(slip_forces_n=())
    slides_at(rig, 8.0)
    released = rig.servos.write_goal_positions

    def stuck(goals_rad):  # the winch ignores the goal that would unwind it: the rig is not healthy
        released({k: v for k, v in goals_rad.items() if v != 0.0 or rig.servos._shut_down})

    rig.servos.write_goal_positions = stuck  # type: ignore[method-assign]
    report = run_on_fakes(rig)
    assert report.exit_code == 1 and report.completed == 0 and "StepTimeoutError" in report.reason
    assert journal_status(tmp_path) == "faulted"


def test_further_drops_after_a_slip_make_it_a_stick_slip_and_replay_counts_them(run_on_fakes, tmp_path):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    tension = rig.load_cell.tension

    def train(t_ns: int) -> float:
        force = tension(t_ns)
        slips = [s for s in rig.line.slips if s.time_ns <= t_ns]
        if len(slips) == 2:  # trial 2: two more drops of 0.5 N, 30 and 60 ms after the first
            since_s = (t_ns - slips[-1].time_ns) / 1e9
            force -= 0.5 * ((since_s >= 0.03) + (since_s >= 0.06))
        return max(force, 0.0)

    rig.load_cell.tension = train
    report = run_on_fakes(rig)
    assert report.exit_code == 0
    assert [t.outcome for t in report.trials] == ["slip", "stick_slip", "slip"]
    assert report.trials[1].slipped and report.estimate.n == 3
    assert report.trials[1].peak_force_n == pytest.approx(SLIP_FORCES_N[1], abs=0.05)
    # Replay finds the same events and counts the same further drops from the logged samples.
    replayed = replay(tmp_path / "out")
    assert replayed.redetection_summary().by_status == {"match": 3}
    assert [r.train_drops for r in replayed.redetections] == [0, 2, 0]
    assert list(replayed.table["outcome"]) == ["slip", "stick_slip", "slip"]


class _SaysJoint:
    """A configuration source that names joint `joint` as the one that moved."""

    def __init__(self, joint: int) -> None:
        self.joint = joint

    def measure(self) -> ConfigurationReading:
        return ConfigurationReading(np.zeros((0, 4, 4)), 0, None, self.joint)


def test_a_slip_of_another_joint_is_kept_out_of_the_fit(run_on_fakes):
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    rig.session.configuration = _SaysJoint(3)
    report = run_on_fakes(rig)
    assert report.exit_code == 1 and report.completed == 3  # no usable slip: the run says so
    assert "every slip was of another joint" in (report.reason or "")
    assert [t.outcome for t in report.trials] == ["other_joint"] * 3
    assert all(t.slipped_joint == 3 and not t.slipped for t in report.trials)
    assert report.estimate is None or report.estimate.n == 0


class _CameraLike:
    """A source that sees the link straight before each slip and, after it, joint `moved` turned by 2°."""

    def __init__(self, moved: int | None) -> None:
        self.moved = moved
        self.calls = 0

    def measure(self) -> ConfigurationReading:
        self.calls += 1
        angles = np.zeros(8)  # the rig config's link: 8 joints
        if self.calls % 2 == 0 and self.moved is not None:  # the second reading of a trial: after the slip
            angles[self.moved - 1] = np.radians(2.0)
        transforms = planar_transforms(angles, 0.03)
        return ConfigurationReading(transforms, 0, tuple(angles), None, (np.radians(0.1),) * 8)


@pytest.mark.parametrize(("moved", "outcome"), [(2, "other_joint"), (1, "slip"), (None, "slip")])
def test_the_joint_that_moved_is_found_from_the_configuration_before_and_after(
    tmp_path, protocol_file, moved, outcome
):
    protocol = protocol_file(QUICK_PROTOCOL.replace("steps: [prompt, ", "steps: [prompt, measure, "))
    rig = fake_rig(slip_forces_n=SLIP_FORCES_N)
    rig.session.configuration = _CameraLike(moved)
    request = RunRequest(protocol_path=protocol, rig_path=None, out_dir=tmp_path / "out", seed=1, run_id="f1")
    report = execute_run(prepare_run(request), rig.session, SilentProgress())
    assert report.exit_code == (0 if outcome == "slip" else 1) and report.completed == 3  # 1: no usable slip
    assert [t.outcome for t in report.trials] == [outcome] * 3
    assert [t.slipped_joint for t in report.trials] == [moved] * 3
