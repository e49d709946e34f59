"""The analysis library (`rig.analysis.open_log`, `open_logs`): the tables, refits, re-detection, report."""

from __future__ import annotations

import json
import math
import shutil
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rig.analysis import LoggedRuns, LogWarning, Refit, open_log, open_logs
from rig.analysis.replay_run import replay
from rig.analysis.trials import TRIAL_COLUMNS, load_trial_table
from rig.errors import InputError
from rig.log.format import schemas as S
from rig.log.reading.reader import read_run
from tests.test_replay import LINK, PROTOCOLS


@pytest.fixture(scope="module")
def runs(tmp_path_factory, run_on_simulated_rig):
    """A smoke run and a small link-validation run, in one directory."""
    root = tmp_path_factory.mktemp("api_logs")
    link_protocol = root / "link_small.yaml"
    link_protocol.write_text(LINK)
    smoke, _ = run_on_simulated_rig(PROTOCOLS / "smoke.yaml", root / "logs", run_id="smoke")
    link, _ = run_on_simulated_rig(link_protocol, root / "logs", run_id="link")
    assert smoke.exit_code == 0 and link.exit_code == 0
    return {"root": root, "smoke": Path(smoke.log), "link": Path(link.log), "dir": root / "logs"}


def test_the_run_json_is_rig_replay_json(runs, run_cli):
    run = open_log(runs["link"])
    assert run.json() == replay(runs["link"]).as_json()
    result = run_cli("replay", runs["link"], "--json")
    assert result.code == 0 and json.loads(result.out) == run.json()


def test_trials_have_the_columns_and_rows_of_the_reports_trials_csv(runs, tmp_path):
    run = open_log(runs["link"])
    written = run.report(tmp_path / "report")
    assert tmp_path / "report" / "trials.csv" in written
    from_csv = load_trial_table(tmp_path / "report" / "trials.csv")
    pd.testing.assert_frame_equal(run.trials, from_csv, check_exact=True)
    assert list(run.trials.columns[: len(TRIAL_COLUMNS)]) == list(TRIAL_COLUMNS)
    assert run.run_id == "link" and run.protocol == "link_small" and run.complete
    assert run.warnings == []


def test_loadcell_is_every_sample_from_the_run_start_with_its_trial(runs):
    run = open_log(runs["smoke"])
    samples = run.loadcell
    logged = read_run(runs["smoke"]).topic(S.LOADCELL)
    assert list(samples.columns) == ["time_s", "force_n", "trial_id", "part"]
    assert len(samples) == len(logged)
    np.testing.assert_array_equal(samples["force_n"].to_numpy(), logged["force_n"].to_numpy())
    assert samples["time_s"].min() >= 0 and samples["time_s"].is_monotonic_increasing
    trials = run.trials
    start_s = float(samples["time_s"].iloc[0])
    for row in trials.itertuples():
        inside = samples[samples["trial_id"] == row.trial_id]["time_s"]
        assert len(inside) > 0
        t0 = (row.start_time_ns - logged["log_time_ns"].iloc[0]) / 1e9 + start_s
        t1 = (row.end_time_ns - logged["log_time_ns"].iloc[0]) / 1e9 + start_s
        assert inside.min() >= t0 - 1e-9 and inside.max() <= t1 + 1e-9
    assert samples["trial_id"].dtype == "Int64"


def test_servos_name_each_servo_with_its_role(runs):
    servos = open_log(runs["smoke"]).servos
    assert {"time_s", "servo_id", "role", "position_rad", "current_a", "trial_id"} <= set(servos.columns)
    assert "winch" in set(servos["role"])
    assert len(servos) == read_run(runs["smoke"]).message_counts[S.SERVO_STATE]


def test_estimates_are_the_online_estimate_after_each_trial(runs):
    run = open_log(runs["link"])
    estimates = run.estimates
    assert list(estimates["trial_id"]) == list(run.trials["trial_id"])
    last = estimates.iloc[-1]
    online = run.replay_result.online_estimate
    assert online is not None and online.fit is not None
    assert last["k_kg_m"] == online.fit.k
    assert (last["k_low_kg_m"], last["k_high_kg_m"]) == online.fit.k_ci
    assert last["capacity_nm"] == online.fit.capacity_nm
    assert math.isnan(estimates.iloc[0]["k_kg_m"]) and estimates.iloc[0]["n"] == 0  # one slip: no fit


def test_configurations_hold_each_measured_angle_with_its_sd(runs):
    configurations = open_log(runs["link"]).configurations
    assert not configurations.empty
    bent = configurations[configurations["stage"] == "bent"]
    assert set(bent["joint"]) == set(range(1, 9))
    assert bent["angle_rad"].notna().all()
    assert {"sd_rad", "commanded_rad", "source", "trial_id", "attempt"} <= set(configurations.columns)
    first = bent[bent["trial_id"] == bent["trial_id"].min()]
    np.testing.assert_allclose(first["commanded_rad"].to_numpy()[:8], np.radians([5] * 8), atol=1e-12)


def test_refit_reproduces_the_offline_fit_and_takes_other_settings(runs):
    run = open_log(runs["link"])
    fit = run.refit()
    assert isinstance(fit, Refit)
    offline = run.replay_result.estimate
    assert offline is not None
    assert fit.k_kg_m == offline.fit.k and (fit.k_low_kg_m, fit.k_high_kg_m) == offline.fit.k_ci
    assert fit.capacity_low_nm < fit.capacity_nm < fit.capacity_high_nm
    assert fit.mu_delta0_low_pa < fit.mu_delta0_pa < fit.mu_delta0_high_pa
    weighted = run.refit(estimator="weighted", level=0.95)
    assert weighted is not None and weighted.estimator == "weighted" and weighted.level == 0.95
    assert run.refit(constant="derived").constant == "derived"
    with pytest.raises(InputError, match="estimator 'median'"):
        run.refit(estimator="median")  # type: ignore[arg-type]


def test_redetect_with_the_logged_parameters_matches_and_with_others_changes(runs):
    run = open_log(runs["smoke"])
    assert set(run.redetect()["redetection"]) == {"match"}
    hair = run.redetect(cusum_threshold_n=0.001, cusum_drift_n_per_s=0, min_drop_n=0)
    assert "changed" in set(hair["redetection"])
    refit = run.refit(trials=hair, masses="redetected_slip_mass_kg")
    assert refit is not None and refit.k_kg_m != run.refit().k_kg_m
    with pytest.raises(InputError, match="no_such_field"):
        run.redetect(no_such_field=1)


def test_open_logs_stacks_the_runs_and_refits_them_as_one(runs):
    logged = open_logs(runs["dir"])
    assert isinstance(logged, LoggedRuns) and sorted(r.run_id for r in logged) == ["link", "smoke"]
    trials = logged.trials
    assert trials.columns[0] == "run_id"
    assert len(trials) == sum(len(r.trials) for r in logged)
    pooled = logged.refit(estimator="paper")
    assert pooled is not None
    assert pooled.n == sum(r.refit(estimator="paper").n for r in logged)
    assert logged["smoke"].run_id == "smoke"


def test_a_resumed_runs_parts_open_as_one_run(runs, tmp_path):
    # A copy of a run as a resumed run's two files: parts merge into one run (same trials twice is warned).
    shutil.copy(runs["smoke"], tmp_path / "r.mcap")
    shutil.copy(runs["smoke"], tmp_path / "r.part2.mcap")
    with pytest.warns(LogWarning, match="second result"):
        logged = open_logs(tmp_path)
    assert len(logged) == 1 and len(logged[0].files) == 2


def test_a_damaged_file_opens_with_warnings(runs, tmp_path):
    data = runs["smoke"].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = open_log(cut)
    messages = [str(w.message) for w in caught if issubclass(w.category, LogWarning)]
    assert any("no footer" in m or "truncated" in m for m in messages), messages
    assert not run.complete and len(run.trials) > 0


def test_a_file_that_is_not_a_rig_log_raises(tmp_path):
    other = tmp_path / "other.mcap"
    other.write_bytes(b"not an mcap")
    with pytest.raises(InputError):
        open_log(other)


def test_payloads_that_do_not_decode_are_counted_in_one_warning(tmp_path, run_cli):
    # A pre-release payload (integer times, no `start` stamp) is skipped with a warning, no traceback.
    from rig.log.format.examples import EXAMPLE_TIME_NS, example_payloads
    from rig.log.writing.writer import RunLogger

    payloads = example_payloads()
    result = {k: v for k, v in payloads[S.TRIAL_RESULT].items() if k not in ("start", "end")}
    result.update(start_time_ns=EXAMPLE_TIME_NS, end_time_ns=EXAMPLE_TIME_NS + 1)
    path = tmp_path / "old.mcap"
    with RunLogger(path, strict=False) as log:
        for i in range(2):
            log.log(S.TRIAL_RESULT, EXAMPLE_TIME_NS + i, result)
        log.log(S.SLIP, EXAMPLE_TIME_NS, {k: v for k, v in payloads[S.SLIP].items() if k != "kind"})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = open_log(path)
    expected = [
        "old.mcap: 1 /rig/slip message could not be decoded "
        "(first: None is not a valid SlipEventKind); skipped",
        "old.mcap: 2 /rig/trial/result messages could not be decoded "
        "(first: start.sec: None is not an integer); skipped",
    ]
    assert [str(w.message) for w in caught if str(w.message) in expected] == expected
    assert len(run.trials) == 0
    done = run_cli("replay", path, "--json")
    assert done.code == 0 and "Traceback" not in done.err
    assert set(expected) <= set(json.loads(done.out)["warnings"])


def test_everything_rig_replay_finds_is_on_the_run(runs):
    run = open_log(runs["link"])
    out = run.json()
    links = run.links
    assert list(links["trial_id"]) == [entry["trial_id"] for entry in out["links"]]
    assert (links["bus_operations"] > 0).all() and (links["loadcell_lines_ok"] > 0).all()
    assert links["bus_operations"].dtype == "Int64"
    assert run.payload_errors is not None and run.payload_errors.as_json() == out["percentage_errors"]
    assert run.base_moments is not None and run.base_moments.as_json() == out["base_moments"]
    assert run.online_agreement.agree and run.online_agreement.as_json() == out["online_agreement"]
    assert run.redetection.matches == len(run.trials) and run.redetection.as_json() == out["redetection"]
    assert run.truth == out["truth"]
