"""The runner on the object-level simulated rig: what it commands, in what order, and how it ends.

Through the public API `prepare_run` / `execute_run`, on the rig `rig run --devices object` runs on,
its seams wrapped (tests/runner_rig.py: recorded servo calls, injected errors, a Ctrl-C at a prompt):
no bytes, no emulators. Slips come from the world, scripted by the rig config (`EXACT_RIG`: no noise;
a slip-kind mix and a seed for creep and stick-slip trials); every expected force, mass and angle is
the world's truth. The byte-level simulated rig (tests/test_runner.py) stays the end-to-end path.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from model.chain import planar_transforms
from rig.analysis.replay_run import replay
from rig.errors import CommunicationError, NotConnectedError, StaleDataError
from rig.hw.dxl.control_table import RAD_PER_PULSE
from rig.hw.seams import ConfigurationReading
from rig.runner.execute import RunRequest, prepare_run
from rig.runner.journal import RunJournal
from rig.runner.ramp import RAMP_GOAL_LEAD_S
from rig.sim.kinds import SlipKind
from tests.helpers import QUICK_PROTOCOL, QUICK_STEPS, quick_protocol
from tests.runner_rig import EXACT_RIG, RunnerRig, assert_released_then_torque_off, execute_on, runner_rig

OVERLOAD = 0x20  # Hardware Error Status bit 5, overload (e-Manual, XM430-W350 control table, address 70)

# A creeping joint yields at its slip load for 10 s, the tension falling by 0.1 %: no drop for the
# detector, so the ramp times out with the line loaded. Trial 1 creeps and trials 2 and 3 slip
# suddenly at seed 8 (the mix's draws, `rig.sim.physics.trial_draws`; the tests check the truth).
_CREEP = "creep_duration_s: [10, 10], creep_drop_fraction: [0.001, 0.001]"
CREEP_THEN_SLIPS_RIG = (
    "extends: simulated\nname: creep\nsimulation:\n  noise_scale: 0\n"
    f"  slips: {{mix: {{sudden: 0.5, creep: 0.5}}, {_CREEP}}}\n"
)
CREEP_THEN_SLIPS_SEED = 8
ALL_CREEP_RIG = (
    "extends: simulated\nname: creep\nsimulation:\n  noise_scale: 0\n"
    f"  slips: {{mix: {{creep: 1.0}}, {_CREEP}}}\n"
)
# The quick protocol with a ramp that times out sooner: 3 x 20 N / (0.6 rad/s x 50 N/rad) + 0.5 s = 2.5 s
# (rig.runner.ramp), not 3 x 70 N / 15 N/s + 5 s = 19 s.
TIMEOUT_PROTOCOL = quick_protocol(
    ramp={"max_force_n": 20.0, "slow_speed_rad_s": 0.6}, limits={"step_timeout_margin_s": 0.5}
)
# Trial 2 a stick-slip train of 3 drops, trials 1 and 3 sudden slips: the draws at seed 1.
STICK_SLIP_RIG = (
    "extends: simulated\nname: stick-slip\nsimulation:\n  noise_scale: 0\n"
    "  slips: {mix: {sudden: 0.5, stick_slip: 0.5}, stick_slip_drops: [3, 3]}\n"
)


@pytest.fixture
def prepare(tmp_path, protocol_file):
    """`prepare(rig_text=EXACT_RIG, protocol=QUICK_PROTOCOL, seed=1)` -> PreparedRun of run f1."""

    def prep(rig_text: str = EXACT_RIG, protocol: str = QUICK_PROTOCOL, seed: int = 1):
        rig_path = tmp_path / "rig.yaml"
        rig_path.write_text(rig_text)
        request = RunRequest(
            protocol_path=protocol_file(protocol),
            rig_path=rig_path,
            out_dir=tmp_path / "out",
            seed=seed,
            run_id="f1",
        )
        return prepare_run(request)

    return prep


@pytest.fixture
def run_exact(prepare):
    """`run_exact(setup=None, **runner_rig kwargs)` -> (report, rig): the quick protocol on `EXACT_RIG`."""

    def run(setup=None, **kwargs):
        prepared = prepare()
        rig = runner_rig(prepared, **kwargs)
        if setup is not None:
            setup(rig)
        return execute_on(prepared, rig), rig

    return run


def journal_status(tmp_path) -> str:
    return RunJournal.load(tmp_path / "out" / "f1.journal.json").status


# ------------------------------------------------------------------------------------------ slips


def test_slips_give_outcome_slip_and_the_estimate_follows(run_exact):
    report, rig = run_exact()
    truth = rig.world.truth()
    assert report.exit_code == 0 and report.completed == 3 and not report.aborted
    assert [t.outcome for t in report.trials] == ["slip"] * 3
    # The world slips in the 1 ms substep after its slip load is passed.
    assert [s.peak_tension_n for s in truth.slips] == pytest.approx(
        [t.slip_force_n for t in truth.trials], abs=0.02
    )
    for trial, true_trial in zip(report.trials, truth.trials, strict=True):
        # 1 kHz at 15 N/s (the slow speed on a 50 N/rad line): 0.015 N a sample.
        assert trial.peak_force_n == pytest.approx(true_trial.slip_force_n, abs=0.05)
    # Trial 1 has no prediction; trial 3 is planned from the fit of trials 1 and 2, exact here.
    assert report.trials[0].predicted_mass_kg is None
    third = report.trials[2]
    assert third.predicted_mass_kg == pytest.approx(third.slip_mass_kg, rel=0.01)
    assert report.estimate.n == 3
    assert report.estimate.k == pytest.approx(truth.joints[0].k_kg_m, rel=0.01)  # the protocol's joint 1
    # Each trial: tare, reel in (fast, then slow from the arm threshold), hold after the slip, unload
    # to the zero-tension angle; and the release at the end goes there too.
    winch = rig.session.winch_id
    goals = [c.args["goals_rad"][winch] for c in rig.servos.calls_to("write_goal_positions")]
    assert goals.count(goals[-1]) == 3 + 1
    assert [t for t, _ in rig.operator.prompts] == [1, 2, 3]
    assert_released_then_torque_off(rig)


def test_connect_sets_up_the_winch_before_torque_on(run_exact):
    _, rig = run_exact()
    winch = rig.session.winch_id
    calls = [c for c in rig.servos.calls if c.name != "read_states"]
    assert calls[0].name == "connect"
    torque_on = next(
        i
        for i, c in enumerate(calls)
        if c.name == "set_torque" and winch in c.args["servo_ids"] and c.args["enabled"]
    )
    before = calls[:torque_on]
    (limit,) = [c.args for c in before if c.name == "set_current_limit" and c.args["servo_id"] == winch]
    (mode,) = [c.args for c in before if c.name == "set_operating_mode" and c.args["servo_id"] == winch]
    assert mode["mode"] == 5 and mode["goal_current_a"] == limit["current_limit_a"]
    assert rig.cell_errors.calls["open"] == 1 and rig.cell_errors.calls["close"] == 1


# ------------------------------------------------------------------------------------------ faults


def test_stale_load_cell_during_the_ramp_stops_released_then_torque_off(run_exact, tmp_path):
    unplugged = []

    def setup(rig: RunnerRig) -> None:
        def unplug(sample) -> None:
            unplugged.append(rig.world.tension_n)
            stale = StaleDataError("load cell sim: no valid sample for 0.201 s; limit 0.2 s")
            rig.cell_errors.raise_while(stale, methods={"poll"})

        rig.when_tension_reaches(5.0, unplug)

    report, rig = run_exact(setup)
    assert report.exit_code == 1 and report.aborted and report.completed == 0
    assert "StaleDataError" in report.reason and "no valid sample" in report.reason
    assert journal_status(tmp_path) == "faulted"
    assert unplugged and unplugged[0] >= 5.0  # the line was loaded when the data stopped
    assert rig.world.truth().slips == ()
    assert_released_then_torque_off(rig)


def test_hardware_error_on_the_winch_reboots_it_releases_the_line_and_repeats_the_trial(run_exact, tmp_path):
    def setup(rig: RunnerRig) -> None:
        rig.when_tension_reaches(
            5.0, lambda s: rig.sim.devices.bus.set_hardware_error(rig.session.winch_id, OVERLOAD)
        )

    report, rig = run_exact(setup)
    # The fault dropped the torque with the line loaded: the winch is rebooted and unwinds; the rig
    # answers healthily again, so the trial is repeated and the run completes.
    assert report.exit_code == 0 and report.completed == 3, report.reason
    assert report.safe_state_verified
    journal = RunJournal.load(tmp_path / "out" / "f1.journal.json")
    assert journal.status == "completed" and journal.retried_trials == [1]
    names = rig.servos.call_names()
    assert names.count("reboot") == 1 and names.index("reboot") < names.index("shutdown")
    assert_released_then_torque_off(rig)
    assert rig.sim.devices.bus.servo(rig.session.winch_id).hardware_error == 0


def test_servo_bus_going_silent_still_attempts_torque_off(run_exact, tmp_path):
    failed_at = []

    def setup(rig: RunnerRig) -> None:
        def cable_pulled(sample) -> None:
            failed_at.append(len(rig.servos.calls))
            rig.bus_errors.raise_while(CommunicationError("servo bus: no reply"))

        rig.when_tension_reaches(5.0, cable_pulled)

    report, rig = run_exact(setup)
    assert report.exit_code == 1 and report.completed == 0
    assert "CommunicationError" in report.reason
    assert journal_status(tmp_path) == "faulted"
    assert "shutdown" in [c.name for c in rig.servos.calls[failed_at[0] :]]  # asked for, though it failed
    assert rig.cell_errors.calls["close"] == 1


# ------------------------------------------------------------------------------------------ Ctrl-C


def test_ctrl_c_at_the_operator_prompt_exits_130_released_then_torque_off(run_exact, tmp_path):
    report, rig = run_exact(interrupt_at_trial=2)
    assert report.exit_code == 130 and report.aborted and report.completed == 1
    assert report.reason == "interrupted by the operator"
    assert journal_status(tmp_path) == "interrupted"
    assert_released_then_torque_off(rig)


def test_ctrl_c_during_the_ramp_exits_130_released_then_torque_off(run_exact, tmp_path):
    loaded = []

    def setup(rig: RunnerRig) -> None:
        def ctrl_c(sample) -> None:
            world = rig.world
            loaded.append(
                (rig.winch_rad, world.line.winch_angle_for_tension_rad(8.0, world.line_take_up_m()))
            )
            raise KeyboardInterrupt  # as a SIGINT arriving in the middle of a control tick

        rig.when_tension_reaches(8.0, ctrl_c)

    report, rig = run_exact(setup)
    assert report.exit_code == 130 and report.completed == 0
    assert journal_status(tmp_path) == "interrupted"
    winch_rad, at_8_n_rad = loaded[0]
    assert winch_rad == pytest.approx(at_8_n_rad, abs=0.01)
    assert_released_then_torque_off(rig)


# ------------------------------------------------------------------- runner bugs these faults found


def test_load_cell_cable_pulled_during_the_ramp_still_releases_before_torque_off(run_exact, tmp_path):
    def setup(rig: RunnerRig) -> None:
        pulled = NotConnectedError("load cell sim: reading failed: cable pulled")
        rig.when_tension_reaches(8.0, lambda s: rig.cell_errors.raise_while(pulled, methods={"poll"}))

    report, rig = run_exact(setup)
    assert report.exit_code == 1 and "NotConnectedError" in report.reason
    assert journal_status(tmp_path) == "faulted"
    assert_released_then_torque_off(rig)


def test_a_failed_safe_state_after_a_fault_is_in_the_report(run_exact):
    def setup(rig: RunnerRig) -> None:
        silent = CommunicationError("servo bus: no reply")
        rig.when_tension_reaches(5.0, lambda s: rig.bus_errors.raise_while(silent))

    report, _ = run_exact(setup)
    assert report.exit_code == 1 and "CommunicationError" in report.reason
    assert "torque off failed" in report.reason


def test_the_ramp_goal_stays_a_short_way_ahead_of_the_winch(run_exact):
    # A host that dies mid-ramp must leave a winch that stops within a short lead, not one reeling on
    # to the end of its travel (20 turns here).
    leads_rad = []

    def setup(rig: RunnerRig) -> None:
        bus, winch = rig.sim.devices.bus, rig.session.winch_id
        write = bus.write_goal_positions

        def noting(goals_rad):
            if winch in goals_rad:
                leads_rad.append(goals_rad[winch] - rig.winch_rad)
            write(goals_rad)

        bus.write_goal_positions = noting  # type: ignore[method-assign]

    report, _ = run_exact(setup)
    assert report.exit_code == 0 and leads_rad
    fast_lead = 1.0 * RAMP_GOAL_LEAD_S  # the protocol's fast speed, rad/s
    assert max(leads_rad) <= fast_lead + RAD_PER_PULSE  # the runner reads the position to a pulse


# ------------------------------------------------------------------- odd slips and step timeouts


def tension_at_prompts(rig: RunnerRig) -> list[float]:
    """A list that gets the world's line tension at every trial's prompt."""
    at_prompt: list[float] = []
    rig.operator.on_prompt = lambda trial: at_prompt.append(rig.world.tension_n)
    return at_prompt


def test_a_ramp_that_times_out_with_the_line_loaded_aborts_the_trial_and_the_run_goes_on(prepare, tmp_path):
    prepared = prepare(CREEP_THEN_SLIPS_RIG, TIMEOUT_PROTOCOL, seed=CREEP_THEN_SLIPS_SEED)
    rig = runner_rig(prepared)
    at_prompt = tension_at_prompts(rig)
    report = execute_on(prepared, rig)
    truth = rig.world.truth()
    assert [t.slip.kind for t in truth.trials] == [SlipKind.CREEP, SlipKind.SUDDEN, SlipKind.SUDDEN]
    assert report.exit_code == 0 and report.completed == 3 and not report.aborted, report.reason
    first, *others = report.trials
    assert first.outcome == "aborted" and "ramp_until_slip exceeded its timeout" in first.reason
    # The line was loaded to the creeping joint's slip load when it timed out.
    assert first.peak_force_n == pytest.approx(truth.trials[0].slip_force_n, abs=0.05)
    assert not first.slipped
    assert [t.outcome for t in others] == ["slip", "slip"] and all(t.reason is None for t in others)
    # The line was released before the next trial: slack at its start, and at the end of the run.
    assert at_prompt[1] < 0.5
    assert report.estimate.n == 2  # the aborted trial is not in the fit
    journal = RunJournal.load(tmp_path / "out" / "f1.journal.json")
    assert journal.status == "completed" and journal.completed[0].outcome == "aborted"
    assert journal.completed[0].reason == first.reason
    assert_released_then_torque_off(rig)


def test_a_run_whose_every_trial_times_out_ends_cleanly(prepare, tmp_path):
    prepared = prepare(ALL_CREEP_RIG, TIMEOUT_PROTOCOL)
    rig = runner_rig(prepared)
    at_prompt = tension_at_prompts(rig)
    report = execute_on(prepared, rig)
    # Every trial done, but nothing measured: the run fails (exit 1) saying so and why.
    assert report.exit_code == 1 and report.completed == 3 and report.aborted
    assert (report.reason or "").startswith("no trial gave a usable slip (3 aborted of 3): every trial")
    assert [t.outcome for t in report.trials] == ["aborted"] * 3
    assert all(p < 0.5 for p in at_prompt)
    assert report.estimate is None or report.estimate.n == 0
    assert journal_status(tmp_path) == "completed"
    assert_released_then_torque_off(rig)


def test_a_step_timeout_whose_release_fails_ends_the_run(prepare, tmp_path):
    prepared = prepare(ALL_CREEP_RIG, TIMEOUT_PROTOCOL)
    rig = runner_rig(prepared)
    bus, winch = rig.sim.devices.bus, rig.session.winch_id
    write = bus.write_goal_positions

    def stuck(goals_rad):  # the winch ignores a goal that would unwind it: the rig is not healthy
        shutting_down = "shutdown" in rig.servos.call_names()
        write({k: v for k, v in goals_rad.items() if k != winch or v >= rig.winch_rad or shutting_down})

    bus.write_goal_positions = stuck  # type: ignore[method-assign]
    report = execute_on(prepared, rig)
    assert report.exit_code == 1 and report.completed == 0 and "StepTimeoutError" in report.reason
    assert journal_status(tmp_path) == "faulted"


def test_further_drops_after_a_slip_make_it_a_stick_slip_and_replay_counts_them(prepare, tmp_path):
    prepared = prepare(STICK_SLIP_RIG)
    rig = runner_rig(prepared)
    report = execute_on(prepared, rig)
    truth = rig.world.truth()
    plans = [t.slip for t in truth.trials]
    assert [p.kind for p in plans] == [SlipKind.SUDDEN, SlipKind.STICK_SLIP, SlipKind.SUDDEN]
    assert report.exit_code == 0
    assert [t.outcome for t in report.trials] == ["slip", "stick_slip", "slip"]
    assert report.trials[1].slipped and report.estimate.n == 3
    assert report.trials[1].peak_force_n == pytest.approx(truth.trials[1].slip_force_n, abs=0.05)
    # Replay finds the same events and counts the further drops (the train's after its first).
    further = [0 if p.train_drops is None else p.train_drops - 1 for p in plans]
    replayed = replay(tmp_path / "out")
    assert replayed.redetection_summary().by_status == {"match": 3}
    assert [r.train_drops for r in replayed.redetections] == further
    assert list(replayed.table["outcome"]) == ["slip", "stick_slip", "slip"]


class _SaysJoint:
    """A configuration source that names joint `joint` as the one that moved."""

    def __init__(self, joint: int) -> None:
        self.joint = joint

    def measure(self) -> ConfigurationReading:
        return ConfigurationReading(np.zeros((0, 4, 4)), 0, None, self.joint)


def test_a_slip_of_another_joint_is_kept_out_of_the_fit(prepare):
    prepared = prepare()
    rig = runner_rig(prepared)
    rig.session = dataclasses.replace(rig.session, configuration=_SaysJoint(3))
    report = execute_on(prepared, rig)
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
            angles[self.moved - 1] = math.radians(2.0)
        transforms = planar_transforms(angles, 0.03)
        return ConfigurationReading(transforms, 0, tuple(angles), None, (math.radians(0.1),) * 8)


@pytest.mark.parametrize(("moved", "outcome"), [(2, "other_joint"), (1, "slip"), (None, "slip")])
def test_the_joint_that_moved_is_found_from_the_configuration_before_and_after(prepare, moved, outcome):
    prepared = prepare(protocol=quick_protocol(block={"steps": ["prompt", "measure", *QUICK_STEPS[1:]]}))
    rig = runner_rig(prepared)
    rig.session = dataclasses.replace(rig.session, configuration=_CameraLike(moved))
    report = execute_on(prepared, rig)
    assert report.exit_code == (0 if outcome == "slip" else 1) and report.completed == 3  # 1: no usable slip
    assert [t.outcome for t in report.trials] == [outcome] * 3
    assert [t.slipped_joint for t in report.trials] == [moved] * 3
