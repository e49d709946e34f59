"""The hostile inputs of the input review: each one works or exits 2 with one line, before anything starts."""

from __future__ import annotations

import copy
import json
import math
import os
from pathlib import Path

import pytest

from rig.errors import InputError
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG
from rig.runner.journal import JOURNAL_FORMAT, RunJournal, content_hash
from rig.runner.run_estimates import load_estimates_file
from tests.helpers import QUICK_LINK_STEPS, QUICK_PROTOCOL, QUICK_STEPS, quick_protocol, shipped_block

REPO = Path(__file__).resolve().parents[1]
PROTOCOLS = REPO / "protocols"

MINIMAL_ESTIMATES = {"n": 3, "k": 0.16, "capacity_nm": 1.58, "capacity_ci_nm": [1.4, 1.7]}
ESTIMATES = {
    **MINIMAL_ESTIMATES, "level": 0.99, "k_ci": [0.14, 0.17], "mu_delta0_ci_pa": [2.6e5, 3.2e5],
}  # fmt: skip
# QUICK_PROTOCOL's settings, one link-validation trial predicted from est.json.
LINK_VALIDATION = quick_protocol(
    name="lv",
    blocks=[
        shipped_block(
            "link_validation",
            1,
            estimates_from="est.json",
            configurations_deg=[[0, 10, 0, 0, 0, 0, 0, 0]],
            steps=QUICK_LINK_STEPS,
        )
    ],
)


def assert_one_line_exit_2(result, *needles):
    assert result.code == 2, result.err
    assert result.out == "" and result.err.startswith("rig: error: ") and result.err.count("\n") == 1
    for needle in needles:
        assert needle in result.err, result.err


# ------------------------------------------------------------------------------------------- dry run


def simulated_config_with(tmp_path: Path, calibration: str) -> Path:
    text = DEFAULT_RIG_CONFIG.read_text(encoding="utf-8")
    marker = "  # calibration: omitted"
    assert marker in text
    path = tmp_path / "rig.yaml"
    path.write_text(text.replace(marker, f"  calibration: {calibration}\n{marker}"), encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (None, "abc: file not found"),
        ("{}", "abc: factor_n_per_count: missing; allowed"),
        ('{"factor_n_per_count": 1e-320}', "allowed"),
    ],
)
def test_dry_run_validates_the_calibration_a_run_would_read(tmp_path, run_cli, content, needle):
    config = simulated_config_with(tmp_path, "abc")
    if content is not None:
        (tmp_path / "abc").write_text(content)
    for extra in (["--dry-run"], []):
        result = run_cli("run", PROTOCOLS / "smoke.yaml", "--rig", config, "--out", tmp_path / "o", *extra)
        assert_one_line_exit_2(result, needle)
    assert not (tmp_path / "o").exists()


def test_dry_run_validates_the_estimates_file(tmp_path, run_cli):
    protocol = tmp_path / "lv.yaml"
    protocol.write_text(LINK_VALIDATION)
    (tmp_path / "est.json").write_text(json.dumps({**ESTIMATES, "capacity_nm": -1}))
    assert_one_line_exit_2(run_cli("run", protocol, "--dry-run"), "est.json: capacity_nm: -1; allowed")
    (tmp_path / "est.json").write_text(json.dumps(ESTIMATES))
    assert run_cli("run", protocol, "--dry-run").code == 0


# --------------------------------------------------------------------------------------- estimates


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"capacity_nm": -1}, "capacity_nm: -1; allowed: a finite number from 1e-06 to 10000"),
        ({"capacity_nm": "1.5"}, "capacity_nm: '1.5'; allowed"),
        ({"capacity_nm": None}, "capacity_nm: missing"),
        ({"k": 1e-320}, "k: 1e-320; allowed"),
        ({"n": 1}, "n: 1; allowed: an integer from 2"),
        ({"n": True}, "n: True; allowed"),
        ({"capacity_ci_nm": [1.6, 1.7]}, "capacity_ci_nm: [1.6, 1.7] for capacity_nm 1.58"),
        ({"capacity_ci_nm": [1.4]}, "capacity_ci_nm: [1.4]; allowed: a list [lower, upper]"),
        ({"level": 1.5}, "level: 1.5; allowed"),
        ({"k_ci": ["a", 1]}, "k_ci[0]: 'a'; allowed: a list [lower, upper] of 2 finite numbers"),
        ({"k_ci": [0.2, 0.1]}, "k_ci: [0.2, 0.1]; allowed"),
        ({"mu_delta0_ci_pa": None}, "mu_delta0_ci_pa: missing; allowed"),
        ({"level": None}, "level: missing"),
        ({"r2": "high"}, "r2: 'high'; allowed: a finite number or null"),
        ({"constant": 5}, "constant: 5; allowed"),
    ],
)
def test_bad_estimates_are_refused_naming_the_field(tmp_path, change, needle):
    path = tmp_path / "est.json"
    path.write_text(json.dumps({**ESTIMATES, **change}))
    with pytest.raises(InputError) as exc:
        load_estimates_file(path)
    assert str(exc.value).startswith(f"{path}: ") and needle in str(exc.value)


def test_estimates_from_a_run_may_hold_nan_but_not_a_null_estimate(tmp_path):
    path = tmp_path / "r.estimates.json"
    path.write_text(json.dumps({"run_id": "r", "estimate": {**ESTIMATES, "r2": math.nan}, "joints": []}))
    summary = load_estimates_file(path)
    assert summary.dfe == 2 and math.isnan(summary.r2) and math.isnan(summary.sse)
    path.write_text('{"run_id": "r", "estimate": null, "joints": []}')
    with pytest.raises(InputError, match="estimate: null"):
        load_estimates_file(path)


def test_a_minimal_estimates_file_is_refused_naming_the_missing_key(tmp_path, run_cli):
    protocol = tmp_path / "lv.yaml"
    protocol.write_text(LINK_VALIDATION)
    (tmp_path / "est.json").write_text(json.dumps(MINIMAL_ESTIMATES))
    assert_one_line_exit_2(run_cli("run", protocol, "--out", tmp_path / "out"), "est.json: k_ci: missing")
    assert not (tmp_path / "out").exists()


def test_rig_fit_output_and_a_short_file_work_end_to_end(tmp_path, run_cli):
    fitted = run_cli("fit", PROTOCOLS / "example_fit.csv", "--radius-m", "0.01", "--json")
    assert fitted.code == 0
    protocol = tmp_path / "lv.yaml"
    protocol.write_text(LINK_VALIDATION)
    for name, estimates in (("fit", fitted.data), ("short", ESTIMATES)):
        (tmp_path / "est.json").write_text(json.dumps(estimates))
        result = run_cli("run", protocol, "--out", tmp_path / "out", "--run-id", name, "--json")
        assert result.code == 0, result.err  # the log's schemas are checked (RIG_LOG_STRICT)
        report = result.data
        assert report["completed"] == 1 and report["trials"][0]["predicted_force_n"] > 0
        assert report["estimate"]["capacity_nm"] == estimates["capacity_nm"]
        written = load_estimates_file(tmp_path / "out" / f"{name}.estimates.json")  # NaN there reads back
        assert written.capacity_nm == estimates["capacity_nm"]


# ----------------------------------------------------------------------------------------- journal


def journal_setup(tmp_path: Path) -> tuple[Path, dict]:
    protocol = tmp_path / "quick.yaml"
    protocol.write_text(QUICK_PROTOCOL)
    record = {
        "trial_id": 1, "kind": "joint_estimation", "repeat": 1, "joint": 1, "distance_m": 0.12,
        "configuration_index": None, "joint_angles_rad": None, "start_time_ns": 1, "end_time_ns": 2,
        "outcome": "slip", "peak_force_n": 13.0, "slip_mass_kg": 1.33, "predicted_force_n": None,
        "predicted_mass_kg": None, "percentage_error": None, "slipped_joint": None, "lever_arms_m": None,
        "tare_n": 0.0,
    }  # fmt: skip
    journal = {
        "format": JOURNAL_FORMAT,
        "run_id": "r1",
        "protocol_path": str(protocol),
        "protocol_hash": content_hash(QUICK_PROTOCOL),
        "rig_path": str(DEFAULT_RIG_CONFIG),
        "rig_hash": content_hash(DEFAULT_RIG_CONFIG.read_text(encoding="utf-8")),
        "seed": 0,
        "planned_trials": [1, 2, 3],
        "completed": [record],
        "logs": [],
        "status": "interrupted",
        "invocations": 1,
    }
    return protocol, journal


def _set(path: str, value):
    def change(journal):
        *parents, last = path.split(".")
        target = journal
        for key in parents:
            target = target[int(key)] if key.isdigit() else target[key]
        target[int(last) if last.isdigit() else last] = value

    return change


DAMAGED = [
    ("seed", _set("seed", "x"), "seed: expected an integer"),
    ("seed-negative", _set("seed", -1), "seed: expected an integer from 0"),
    ("completed-int", _set("completed", [1]), "completed[0]: expected a trial record"),
    ("completed-map", _set("completed", {"a": 1}), "completed: expected a list"),
    ("kind", _set("completed.0.kind", "twist"), "completed[0]:"),
    ("missing-id", lambda j: j["completed"][0].pop("trial_id"), "completed[0]: field 'trial_id' is missing"),
    ("tare", _set("completed.0.tare_n", [1]), "completed[0]:"),
    ("distance", _set("completed.0.distance_m", 1e-320), "completed[0].distance_m: 1e-320 for a slip"),
    ("distance-null", _set("completed.0.distance_m", None), "completed[0].distance_m: None for a slip"),
    ("mass-huge", _set("completed.0.slip_mass_kg", 10**400), "completed[0]:"),
    ("unplanned", _set("completed.0.trial_id", 9), "completed: trial ids repeated or not in planned"),
    ("planned-twice", _set("planned_trials", [1, 1]), "planned_trials: a trial id appears twice"),
    ("status", _set("status", []), "status: []; allowed: running"),
    ("logs", _set("logs", [1]), "logs[0]: expected a path"),
    ("lever-arms", _set("completed.0.kind", "link_validation"), "completed[0].lever_arms_m: None"),
]


@pytest.mark.parametrize(("change", "needle"), [d[1:] for d in DAMAGED], ids=[d[0] for d in DAMAGED])
def test_damaged_journal_is_refused_with_one_line(tmp_path, run_cli, change, needle):
    protocol, journal = journal_setup(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    path = RunJournal.path_for(out, "r1")
    path.write_text(json.dumps(journal))
    assert run_cli("run", protocol, "--out", out, "--resume", "r1", "--dry-run").code == 0
    damaged = copy.deepcopy(journal)
    change(damaged)
    path.write_text(json.dumps(damaged))
    result = run_cli("run", protocol, "--out", out, "--resume", "r1", "--dry-run")
    assert_one_line_exit_2(result, str(path), needle)


@pytest.mark.parametrize(
    ("raw", "needle"),
    [
        (b'{"format": "rig-journal/1", "run_id": "\xff"}', "not UTF-8 text (byte 0xff at line 1)"),
        (b"[" * 5000, "nested too deeply"),
        (b'{"format": "rig-journal/1", "seed": NaN}', "NaN is not a JSON number"),
        (b"", "malformed JSON at line 1, column 1"),
    ],
)
def test_unreadable_journal_is_refused_with_one_line(tmp_path, run_cli, raw, needle):
    protocol, _ = journal_setup(tmp_path)
    path = RunJournal.path_for(tmp_path, "r1")
    path.write_bytes(raw)
    assert_one_line_exit_2(run_cli("run", protocol, "--out", tmp_path, "--resume", "r1"), needle)


def test_a_journal_that_does_not_fit_the_rig_is_refused(tmp_path, run_cli):
    protocol, journal = journal_setup(tmp_path)
    record = journal["completed"][0]
    record.update(kind="link_validation", lever_arms_m=[0.1, 0.2], peak_force_n=5.0, distance_m=None)
    path = RunJournal.path_for(tmp_path, "r1")
    path.write_text(json.dumps(journal))
    result = run_cli("run", protocol, "--out", tmp_path, "--resume", "r1", "--dry-run")
    assert_one_line_exit_2(result, "trial 1: cannot be replayed on this rig: lever_arms_m has 2 values")


# ------------------------------------------------------------------------------------ rig sim options


@pytest.mark.parametrize(
    "options",
    [
        ["--gain-counts-per-n", "nan"],
        ["--noise-counts", "inf"],
        ["--offset-counts", "1e300"],
        ["--drift-counts-per-s=-inf"],
        ["--rate", "nan"],
        ["--seed", "-1"],
        ["--profile", "constant:nan"],
        ["--profile", "sawtooth:20:inf"],
        ["--fault", "silence:inf:1"],
        ["--fault", "silence:1:nan"],
        ["--fault", "garbage:nan"],
        ["--fault", "gap:0.1:2"],
        ["--fault", "x\ny"],
    ],
)
def test_rig_sim_loadcell_refuses_bad_options_before_serving(tmp_path, run_cli, options):
    link = tmp_path / "lc"
    assert_one_line_exit_2(run_cli("sim", "loadcell", "--link", link, *options))
    assert not os.path.lexists(link)


@pytest.mark.parametrize(
    ("options", "needle"),
    [
        (["--fault", "drop:1:2:3"], "not a fault spec"),
        (["--fault", "delay:1:nan"], "delay ms 'nan' is not an integer"),
        (["--fault", "hwerror:1:" + "9" * 5000], "bits"),
        (["--fault", "\x00:\n"], "\\x00:\\n"),
        (["--ids", "1,,2"], "'' is not an integer"),
    ],
)
def test_rig_sim_servos_refuses_bad_options_before_serving(tmp_path, run_cli, options, needle):
    link = tmp_path / "dx"
    assert_one_line_exit_2(run_cli("sim", "servos", "--link", link, *options), needle)
    assert not os.path.lexists(link)


def test_rig_sim_link_that_cannot_be_made(tmp_path, run_cli):
    blocker = tmp_path / "file"
    blocker.write_text("")
    result = run_cli("sim", "loadcell", "--link", blocker / "lc")
    assert_one_line_exit_2(result, f"--link {blocker / 'lc'}: cannot create the link")
    result = run_cli("sim", "servos", "--link", blocker)
    assert_one_line_exit_2(result, "exists and is not a symlink")


# ------------------------------------------------------------------------------------------- misc


def test_a_key_with_a_line_break_still_gives_one_line(tmp_path, run_cli):
    path = tmp_path / "link.yaml"
    path.write_text('"a\\nb": 1\n')
    assert_one_line_exit_2(run_cli("predict", path), "a\\nb")


def test_protocol_prompt_and_size_limits(tmp_path, run_cli):
    path = tmp_path / "p.yaml"
    path.write_text(
        quick_protocol(block={"steps": [{"prompt": {"text": "{joint:>999999999}"}}, *QUICK_STEPS[1:]]})
    )
    assert_one_line_exit_2(
        run_cli("run", path, "--dry-run"), "placeholder '{joint:>999999999}' is not allowed"
    )
    path.write_text(quick_protocol(block={"repeats": 100, "distances_m": [0.1] * 101}))
    assert_one_line_exit_2(run_cli("run", path, "--dry-run"), "more than 10000 trials")


def test_rig_run_out_must_be_a_directory(tmp_path, run_cli):
    blocker = tmp_path / "file"
    blocker.write_text("")
    for extra in (["--dry-run"], []):
        result = run_cli("run", PROTOCOLS / "smoke.yaml", "--out", blocker / "logs", *extra)
        assert_one_line_exit_2(result, f"{blocker} is not a directory")


@pytest.mark.parametrize(
    ("options", "needle"),
    [
        (["--reference-kg", "1e-320"], "--reference-kg 1e-320; allowed"),
        (["--reference-kg", "1", "--temperature-c", "nan"], "--temperature-c nan; allowed: -100 to 200"),
        (["--reference-kg", "1", "--serial", "a\nb"], "--serial 'a\\nb': allowed: printable text"),
        (["--reference-kg", "1", "--stale-timeout-s", "1e-320"], "--stale-timeout-s 1e-320"),
    ],
)
def test_rig_calibrate_options_fit_the_file_it_writes(tmp_path, run_cli, options, needle):
    out = tmp_path / "cal.json"
    assert_one_line_exit_2(run_cli("calibrate", "--sim", "--yes", "--out", out, *options), needle)
    assert not out.exists()
