"""The protocol runner on the built-in simulated rig: results, safety, interlocks, resume."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from model.fit import SUMMARY_KEYS
from rig.cli import main
from rig.errors import InputError
from rig.inputs.rig_config import load_rig_config
from rig.runner.journal import RunJournal
from tests.helpers import QUICK_PROTOCOL, QUICK_STEPS, link_small_protocol, quick_protocol

PROTOCOLS = Path(__file__).resolve().parent.parent / "protocols"


def test_smoke_run_json(tmp_path, capsys):
    code = main(["run", str(PROTOCOLS / "smoke.yaml"), "--out", str(tmp_path), "--json", "--run-id", "s1"])
    out = capsys.readouterr().out
    assert code == 0
    report = json.loads(out)
    assert report["run_id"] == "s1" and report["completed"] == 2 and not report["aborted"]
    assert Path(report["log"]).is_file() and report["logs"] == [report["log"]]
    assert list(report["estimate"])[: len(SUMMARY_KEYS)] == list(SUMMARY_KEYS)
    assert report["estimate"]["estimator"] == "auto" and report["estimate"]["paper"]["n"] == 2
    assert report["estimate"]["n"] == 2
    for key in ("k", "capacity_nm", "mu_delta0_pa"):
        assert report["truth"][key] > 0
    for trial in report["trials"]:
        assert trial["outcome"] == "slip"
        assert trial["peak_force_n"] == pytest.approx(trial["slip_mass_kg"] * 9.8)
    journal = RunJournal.load(tmp_path / "s1.journal.json")
    assert journal.status == "completed" and journal.completed_ids == {1, 2}


def test_joint_estimation_recovers_the_true_capacity(sim_run, protocol_file, assert_safe):
    report, sim = sim_run(protocol_file(QUICK_PROTOCOL))
    assert report.exit_code == 0 and report.completed == 3
    truth = report.truth
    # Three slips with the preset's trial-to-trial scatter (sd 8.5 %): within 15 % of the hidden k.
    assert report.estimate.k == pytest.approx(truth.k_kg_m, rel=0.15)
    lo, hi = report.estimate.k_ci
    assert lo < truth.k_kg_m < hi
    assert_safe(sim)
    # The third trial was planned from the fit of the first two: a prediction within 3 scatter sd.
    third = report.trials[2]
    assert report.trials[0].predicted_mass_kg is None
    assert third.predicted_mass_kg == pytest.approx(third.slip_mass_kg, rel=0.3)


def test_dry_run_moves_nothing_and_writes_nothing(tmp_path, capsys):
    code = main(["run", str(PROTOCOLS / "joint_estimation.yaml"), "--dry-run", "--out", str(tmp_path / "o")])
    out = capsys.readouterr().out
    assert code == 0
    assert "24 trials" in out and "estimated duration" in out and "limit checks" in out
    assert not (tmp_path / "o").exists()
    assert main(["run", str(PROTOCOLS / "link_validation.yaml"), "--dry-run", "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert len(plan["trials"]) == 37 and all(c["ok"] for c in plan["limit_checks"])
    assert plan["estimated_duration_s"] > 0


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        ({"detector": {"drop_fraction": None, "drop_fracton": 0.15}}, "drop_fracton"),
        ({"block": {"distances_m": [0.12, -0.2]}}, "distances_m[1]"),
        ({"ramp": {"max_force_n": 80.0}}, "max_force_n"),
        ({"format": "rig-protocol/9"}, "format"),
        ({"block": {"steps": QUICK_STEPS[:-1]}}, "unload"),
        ({"block": {"joint": 12}}, "joint"),
    ],
    ids=[
        "misspelt-detector-field",
        "negative-distance",
        "max-force-above-ceiling",
        "format",
        "no-unload",
        "joint",
    ],
)
def test_bad_protocol_exits_2_and_starts_nothing(tmp_path, capsys, edit, needle, protocol_file):
    path = protocol_file(quick_protocol(**edit))
    code = main(["run", str(path), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err and err.count("\n") == 1
    assert needle in err and str(path) in err
    assert not (tmp_path / "o").exists()


def test_limit_check_against_the_rig_exits_2(tmp_path, capsys, protocol_file):
    path = protocol_file(quick_protocol(limits={"force_ceiling_n": 95.0}))
    assert main(["run", str(path), "--out", str(tmp_path / "o")]) == 2
    assert "limit check failed" in capsys.readouterr().err


def test_force_ceiling_interlock_stops_safely(tmp_path, sim_run, protocol_file, assert_safe):
    # A fast ramp straight to a low ceiling: the tension overshoots the ceiling within one tick.
    body = quick_protocol(
        detector={"arm_threshold_n": 9.5},
        ramp={"fast_speed_rad_s": 15.0, "max_force_n": 9.8},
        limits={"force_ceiling_n": 10.0},
    )
    report, sim = sim_run(protocol_file(body))
    assert report.exit_code == 1 and report.aborted
    assert "above the ceiling" in report.reason
    assert_safe(sim)
    assert RunJournal.load(tmp_path / "out" / "r1.journal.json").status == "faulted"


def test_stale_load_cell_stops_safely(sim_run, protocol_file, assert_safe):
    def unplug_during_first_ramp(sim):
        sim.devices.loadcell_emulator.inject_silence(5.0, at_ns=3_000_000_000)

    report, sim = sim_run(protocol_file(QUICK_PROTOCOL), patch=unplug_during_first_ramp)
    assert report.exit_code == 1
    assert "StaleDataError" in report.reason
    assert_safe(sim)


def test_a_hardware_error_that_comes_back_stops_the_run_safely_after_the_retries(
    tmp_path, sim_run, protocol_file, assert_safe
):
    def overload_at_every_start_of_trial_2(sim):
        bus = sim.devices.bus
        person = sim.session.operator
        original = person.confirm

        def confirm(request, keep_alive) -> None:  # the prompt that starts each attempt of trial 2
            if request.trial is not None and request.trial.trial_id == 2:
                bus.set_hardware_error(1, 0x20)
            original(request, keep_alive)

        person.confirm = confirm

    report, sim = sim_run(protocol_file(QUICK_PROTOCOL), patch=overload_at_every_start_of_trial_2)
    assert report.exit_code == 1 and report.completed == 1
    assert "overload" in report.reason
    # Each start of trial 2 latches the error again: rebooted and repeated twice, then the run stops.
    assert RunJournal.load(tmp_path / "out" / "r1.journal.json").retried_trials == [2, 2]
    assert_safe(sim)


def test_interrupt_then_resume_completes_without_repeats(tmp_path, sim_run, protocol_file, assert_safe):
    protocol = protocol_file(QUICK_PROTOCOL)

    def interrupt_at_trial_2(sim):
        person = sim.session.operator

        class Operator:  # the person, who stops the run at trial 2's prompt
            def confirm(self, request, keep_alive):
                if request.trial is not None and request.trial.trial_id == 2:
                    raise KeyboardInterrupt
                person.confirm(request, keep_alive)

        sim.session.operator = Operator()

    report, sim = sim_run(protocol, patch=interrupt_at_trial_2)
    assert report.exit_code == 130 and report.completed == 1
    assert_safe(sim)
    assert RunJournal.load(tmp_path / "out" / "r1.journal.json").status == "interrupted"

    resumed, sim2 = sim_run(protocol, resume="r1")
    assert resumed.exit_code == 0
    ids = [t.trial_id for t in resumed.trials]
    assert ids == [1, 2, 3]
    assert len(resumed.logs) == 2 and resumed.logs[1].endswith("r1.part2.mcap")
    # The resumed part's virtual time starts after the first part's: the logs never overlap.
    assert resumed.trials[1].start_time_ns > resumed.trials[0].end_time_ns
    assert resumed.estimate.n == 3
    assert_safe(sim2)
    with pytest.raises(InputError, match="already completed"):
        sim_run(protocol, resume="r1")


def test_resume_refuses_an_edited_protocol(sim_run, protocol_file):
    protocol = protocol_file(QUICK_PROTOCOL)

    def stop_early(sim):
        class Operator:
            def confirm(self, request, keep_alive):
                raise KeyboardInterrupt

        sim.session.operator = Operator()

    sim_run(protocol, patch=stop_early)
    protocol.write_text(quick_protocol(block={"repeats": 2}))
    with pytest.raises(InputError, match="changed since run r1 started"):
        sim_run(protocol, resume="r1")


def test_link_validation_predicts_from_the_rigs_own_estimates(sim_run, protocol_file, assert_safe):
    report, sim = sim_run(protocol_file(link_small_protocol(name=None, estimator="paper")))
    assert report.exit_code == 0 and report.completed == 4
    estimation = [t for t in report.trials if t.kind == "joint_estimation"]
    validation = [t for t in report.trials if t.kind == "link_validation"]
    for trial in validation:
        assert trial.predicted_mass_kg is not None and len(trial.lever_arms_m) == 8
        assert abs(trial.percentage_error) < 60
    # The first prediction comes from the rig's own two-point fit (every joint's prior is the
    # fitted capacity), never from the simulator's truth: f* = capacity / largest lever arm.
    fitted_capacity = sum(t.peak_force_n * t.distance_m / t.distance_m**2 for t in estimation) / sum(
        1 / t.distance_m**2 for t in estimation
    )
    first = validation[0]
    expected_force = fitted_capacity / max(first.lever_arms_m)
    assert first.predicted_force_n == pytest.approx(expected_force, rel=2e-3)
    pe = report.percentage_errors
    assert pe.n == 2 and math.isfinite(pe.mean_pct)
    assert len(report.joints) == 8
    assert_safe(sim)


def test_rig_config_defaults_to_the_simulated_rig():
    config = load_rig_config(None)
    assert config.kind == "simulated" and config.article.joint_count == 8
