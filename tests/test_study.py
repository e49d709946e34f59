"""`rig study`: seeds syntax, the Cramér-Rao bound, the statistics, the table, the executors and the CLI."""

from __future__ import annotations

import json
import math
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from model.k_estimators import ESTIMATOR_NAMES, crlb_k, estimate_k
from rig.cli import main
from rig.errors import InputError
from rig.study import table as table_module
from rig.study.executor import run_local, seed_chunks
from rig.study.seeds import parse_seeds
from rig.study.statistics import clopper_pearson, summarise
from rig.study.table import TABLE_NAME, write_table
from rig.study.worker import EstimatorResult, JointResult, RunRecord, StudySpec
from tests.helpers import bare_protocol, shipped_block

REPO = Path(__file__).resolve().parents[1]
SMOKE = REPO / "protocols" / "smoke.yaml"
JSON_KEYS = {"protocol", "seeds", "runs", "aborted", "estimators"}
ESTIMATOR_KEYS = {
    "coverage",
    "coverage_ci",
    "bias_rel",
    "rmse_rel",
    "mse_over_crlb",
    "mean_trials",
    "median_trials",
    "p90_trials",
    "coverage_by_stop",
}


# ----- seeds -------------------------------------------------------------------------------------


def test_seeds_ranges_lists_and_combinations() -> None:
    assert parse_seeds("0-4") == (0, 1, 2, 3, 4)
    assert parse_seeds("0,3,7") == (0, 3, 7)
    assert parse_seeds("5, 0-2 ,9") == (5, 0, 1, 2, 9)
    assert parse_seeds("1-3,2-4") == (1, 2, 3, 4)  # each seed once


@pytest.mark.parametrize("text", ["", "a", "1-", "-3", "3-1", "1,,2", "1.5", "0-999999999", "1e3"])
def test_seeds_bad_syntax_is_an_input_error(text: str) -> None:
    with pytest.raises(InputError, match="--seeds"):
        parse_seeds(text)


# ----- the Cramér-Rao bound -------------------------------------------------------------------------


def test_crlb_multiplicative_is_the_variance_of_the_mean_of_m_l() -> None:
    distances = [0.03, 0.1, 0.25] * 4
    k, b = 0.16, 0.085
    assert crlb_k(distances, k, 0.0, b) == pytest.approx(b**2 * k**2 / len(distances), rel=1e-12)


def test_crlb_additive_is_the_weighted_least_squares_variance() -> None:
    distances = np.array([0.03, 0.1, 0.25] * 4)
    a = 0.05
    expected = a**2 / float(np.sum(1.0 / distances**2))
    assert crlb_k(distances, 0.16, a, 0.0) == pytest.approx(expected, rel=1e-12)


def test_crlb_mixed_is_above_either_pure_shape() -> None:
    """Adding a second source of scatter (and a nuisance parameter for it) can only lose information."""
    distances = [0.03, 0.06, 0.1, 0.15, 0.2, 0.25] * 3
    k, a, b = 0.16, 0.05, 0.085
    mixed = crlb_k(distances, k, a, b)
    assert mixed > crlb_k(distances, k, a, 0.0)
    assert mixed > crlb_k(distances, k, 0.0, b)


def test_crlb_is_reached_by_the_mean_of_m_l_in_a_simulation() -> None:
    """Monte Carlo: under multiplicative scatter the mean of m·l has variance equal to the bound."""
    rng = np.random.default_rng(5)
    distances = np.array([0.1, 0.15, 0.2, 0.25] * 3)
    k, b = 0.16, 0.085
    masses = k / distances * (1 + b * rng.standard_normal((20000, distances.size)))
    estimates = (masses * distances).mean(axis=1)
    assert float(np.var(estimates)) == pytest.approx(crlb_k(distances, k, 0.0, b), rel=0.05)


def full_information_bound(distances, k, a, b):
    """var(k̂) bound from the whole Fisher information over (k, a², b²) (the nuisances the truth has)."""
    inv_l = 1.0 / np.asarray(distances, dtype=float)
    big_a, big_b = a**2, b**2
    v = big_a + big_b * (k * inv_l) ** 2
    dmu = [inv_l]
    dv = [2.0 * big_b * k * inv_l**2]
    if big_a > 0:
        dmu.append(np.zeros_like(inv_l))
        dv.append(np.ones_like(inv_l))
    if big_b > 0:
        dmu.append(np.zeros_like(inv_l))
        dv.append(k**2 * inv_l**2)
    info = np.array(
        [
            [np.sum(dmu[j] * dmu[i] / v + dv[j] * dv[i] / (2.0 * v**2)) for i in range(len(dmu))]
            for j in range(len(dmu))
        ]
    )
    return float(np.linalg.inv(info)[0, 0])


@pytest.mark.parametrize(("a", "b"), [(0.05, 0.0), (0.0, 0.085), (0.05, 0.085), (0.2, 0.01)])
def test_crlb_equals_the_full_information_bound_with_the_scatter_as_nuisance(a, b) -> None:
    distances = [0.03, 0.06, 0.1, 0.15, 0.2, 0.25] * 3
    assert crlb_k(distances, 0.16, a, b) == pytest.approx(
        full_information_bound(distances, 0.16, a, b), rel=1e-9
    )


def test_crlb_without_scatter_or_distances_is_nan() -> None:
    assert math.isnan(crlb_k([0.1, 0.2], 0.16, 0.0, 0.0))
    assert math.isnan(crlb_k([], 0.16, 0.0, 0.1))


# ----- statistics ----------------------------------------------------------------------------------


def test_clopper_pearson_known_values() -> None:
    low, high = clopper_pearson(0, 10)
    assert low == 0.0 and high == pytest.approx(1 - 0.025 ** (1 / 10), rel=1e-9)
    low, high = clopper_pearson(10, 10)
    assert high == 1.0 and low == pytest.approx(0.025 ** (1 / 10), rel=1e-9)
    low, high = clopper_pearson(99, 100)
    assert low == pytest.approx(0.9455, abs=1e-4) and high == pytest.approx(0.99975, abs=1e-5)


def _record(
    seed: int, k_hat: float, half: float, *, status: str = "completed", trials: int = 24
) -> RunRecord:
    k_true = 0.2
    estimates = tuple(
        EstimatorResult(
            name, k_hat, k_hat - half, k_hat + half, half / 3, trials, 0, "multiplicative", 0.0, 0.1
        )
        for name in ESTIMATOR_NAMES
    )
    joint = JointResult(
        1,
        k_true,
        0.0,
        0.1,
        (0.1,) * trials,
        (k_true / 0.1,) * trials,
        (False,) * trials,
        trials,
        0,
        0,
        1e-4,
        estimates,
    )
    return RunRecord(seed, status, None if status == "completed" else "boom", 24, trials, 0.1, (joint,))


def test_summary_scores_completed_runs_and_counts_aborted_ones() -> None:
    records = [
        _record(0, 0.21, 0.02),  # covered, +5 %
        _record(1, 0.17, 0.02),  # missed, -15 %
        _record(2, 0.20, 0.01, trials=12),  # covered, exact
        _record(3, 0.50, 0.01, status="aborted", trials=3),  # not scored
    ]
    summary = summarise("p.yaml", [0, 1, 2, 3], records, ESTIMATOR_NAMES, 0.99)
    assert summary.runs == 4 and summary.aborted == 1
    assert summary.aborted_reasons == ((3, "boom"),)
    e = summary.estimators["paper"]
    assert e.cases == 3
    assert e.coverage == pytest.approx(2 / 3)
    assert e.coverage_ci == clopper_pearson(2, 3)
    assert e.bias_rel == pytest.approx((0.05 - 0.15 + 0.0) / 3)
    assert e.rmse_rel == pytest.approx(math.sqrt((0.05**2 + 0.15**2) / 3))
    assert e.mse_over_crlb == pytest.approx((0.01**2 + 0.03**2 + 0.0) / 3 / 1e-4)
    assert e.mean_trials == pytest.approx((24 + 24 + 12) / 3)
    assert (e.median_trials, e.p90_trials) == (24, 24)
    assert e.coverage_by_stop == ()  # no adaptive block
    assert set(summary.as_json()) == JSON_KEYS
    assert set(summary.as_json()["estimators"]["paper"]) == ESTIMATOR_KEYS


# ----- the table ------------------------------------------------------------------------------------


def test_table_has_a_row_per_run_joint_and_estimator(tmp_path: Path) -> None:
    aborted_early = RunRecord(9, "aborted", "ConfigError: bad", 24, 0, 0.0, ())
    path = write_table(tmp_path / "out", [_record(0, 0.21, 0.02), aborted_early], ESTIMATOR_NAMES)
    table = pq.read_table(path).to_pylist()
    assert len(table) == 2 * len(ESTIMATOR_NAMES)
    assert {r["seed"] for r in table} == {0, 9}
    assert all(r["covered"] for r in table if r["seed"] == 0)
    assert all(r["reason"] == "ConfigError: bad" for r in table if r["seed"] == 9)
    assert os.listdir(tmp_path / "out") == [TABLE_NAME]


def test_table_has_the_mode_open_would_give_it(tmp_path: Path) -> None:
    old = os.umask(0o002)  # a lab group sharing the study's files
    try:
        path = write_table(tmp_path, [_record(0, 0.21, 0.02)], ESTIMATOR_NAMES)
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o664


def test_table_is_written_whole_or_not_at_all(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(table: object, where: str) -> None:
        Path(where).write_bytes(b"PAR1 half")
        raise KeyboardInterrupt

    monkeypatch.setattr(table_module.pq, "write_table", broken)
    with pytest.raises(KeyboardInterrupt):
        write_table(tmp_path, [_record(0, 0.21, 0.02)], ESTIMATOR_NAMES)
    assert os.listdir(tmp_path) == []


# ----- running -------------------------------------------------------------------------------------


def _without_wall_time(records: list[RunRecord]) -> list[tuple[object, ...]]:
    return sorted((r.seed, r.status, r.reason, r.trials_completed, r.joints) for r in records)


@pytest.mark.slow
def test_a_failing_run_is_aborted_and_the_study_goes_on(monkeypatch: pytest.MonkeyPatch) -> None:
    from rig.study import worker

    real = worker.open_simulated_rig

    def flaky(prepared: object, *, devices: str) -> object:
        if prepared.journal.seed == 1:  # type: ignore[attr-defined]
            raise RuntimeError("simulated crash")
        return real(prepared, devices=devices)  # type: ignore[arg-type]

    monkeypatch.setattr(worker, "open_simulated_rig", flaky)
    records = run_local(StudySpec(str(SMOKE), None, "object"), [0, 1, 2], 1, lambda r: None)
    by_seed = {r.seed: r for r in records}
    assert by_seed[1].status == "aborted" and by_seed[1].reason == "RuntimeError: simulated crash"
    assert by_seed[0].status == by_seed[2].status == "completed"


@pytest.mark.slow
@pytest.mark.subprocess
def test_processes_and_dask_give_the_in_process_results() -> None:
    spec = StudySpec(str(SMOKE), None, "object")
    seeds = [0, 1, 2]
    alone = run_local(spec, seeds, 1, lambda r: None)
    in_processes = run_local(spec, seeds, 2, lambda r: None)
    assert _without_wall_time(in_processes) == _without_wall_time(alone)
    assert all(r.status == "completed" for r in alone)
    distributed = pytest.importorskip("distributed")
    from rig.study.executor import run_dask

    with distributed.LocalCluster(processes=False, n_workers=1, threads_per_worker=1) as cluster:
        on_dask = run_dask(spec, seeds, cluster.scheduler_address, lambda r: None)
    assert _without_wall_time(on_dask) == _without_wall_time(alone)


# ----- the command ---------------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_json_has_exactly_the_documented_keys(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["study", str(SMOKE), "--seeds", "0,1", "--jobs", "1", "--json", "--out", str(tmp_path)])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == JSON_KEYS
    assert out["seeds"] == [0, 1] and out["runs"] == 2 and out["aborted"] == 0
    assert set(out["estimators"]) == set(ESTIMATOR_NAMES)
    for entry in out["estimators"].values():
        assert set(entry) == ESTIMATOR_KEYS
        assert len(entry["coverage_ci"]) == 2
    rows = pq.read_table(tmp_path / TABLE_NAME).to_pylist()
    assert len(rows) == 2 * len(ESTIMATOR_NAMES)
    for row in rows:  # the table holds each run's data: refitting it gives the row's estimate
        assert len(row["masses_kg"]) == len(row["censored"]) == len(row["distances_m"]) > 0
        refit = estimate_k(row["estimator"], row["distances_m"], row["masses_kg"], row["censored"])
        assert refit.k == row["k_kg_m"]


def _link_only_protocol(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> Path:
    assert main(["fit", str(REPO / "protocols" / "example_fit.csv"), "--radius-m", "0.005", "--json"]) == 0
    estimates = tmp_path / "estimates.json"
    estimates.write_text(capsys.readouterr().out)
    path = tmp_path / "link_only.yaml"
    validation = shipped_block(
        "link_validation", 1, estimates_from=str(estimates), configurations_deg=[[0] * 8]
    )
    path.write_text(bare_protocol("link_only", [validation]))
    return path


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--seeds", "3-1"], "--seeds"),
        (["--seeds", "x"], "--seeds"),
        (["--seeds", "0", "--jobs", "0"], "--jobs"),
    ],
)
def test_cli_bad_input_exits_2(args: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["study", str(SMOKE), *args]) == 2
    assert message in capsys.readouterr().err


def test_cli_unknown_device_level_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["study", str(SMOKE), "--seeds", "0", "--devices", "bits"])
    assert exit_info.value.code == 2
    assert "--devices" in capsys.readouterr().err


def test_cli_link_validation_only_is_not_supported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    protocol = _link_only_protocol(tmp_path, capsys)
    code = main(["study", str(protocol), "--seeds", "0"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "not supported" in err
    assert "blocks: link_validation x 1;" in err  # names the kinds it found


def test_cli_scheduler_without_dask_names_the_extra(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if not installed
    code = main(["study", str(SMOKE), "--seeds", "0", "--scheduler", "tcp://127.0.0.1:1"])
    assert code == 2
    assert "study` extra" in capsys.readouterr().err


def _wait_for_workers(pid: int, count: int, timeout_s: float = 30.0) -> None:
    """Until process `pid` has `count` children (Linux's /proc; elsewhere a fixed 6 s)."""
    tasks = Path(f"/proc/{pid}/task")
    if not tasks.is_dir():
        time.sleep(6)
        return
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        children = [c for task in tasks.iterdir() for c in (task / "children").read_text().split()]
        if len(children) >= count:
            return
        time.sleep(0.05)
    pytest.fail(f"the study did not start {count} workers within {timeout_s:g} s")


@pytest.mark.slow
@pytest.mark.subprocess
def test_ctrl_c_stops_workers_and_writes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rig.cli",
            "study",
            str(SMOKE),
            "--seeds",
            "0-199",
            "--jobs",
            "2",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        start_new_session=True,
    )
    _wait_for_workers(process.pid, 2)
    time.sleep(0.5)  # into their first runs
    os.killpg(process.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    try:
        _, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 130, err.decode()
    assert not out.exists() or not any(out.iterdir())
    # No worker outlives the study: the process group empties (helper processes go with the parent).
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            os.killpg(process.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail("processes of the study are still running after it exited")


def test_ctrl_c_in_process_stops_the_study_not_just_the_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """With --jobs 1 the runner turns Ctrl-C into an interrupted run; the study must stop too."""
    from rig.errors import ExitCode
    from rig.runner.trial_runner import RunOutcome, TrialRunner

    def interrupted(self: TrialRunner, trials: object) -> RunOutcome:
        return RunOutcome(ExitCode.INTERRUPTED, "interrupted", "interrupted by the operator")

    monkeypatch.setattr(TrialRunner, "run", interrupted)
    seen: list[RunRecord] = []
    with pytest.raises(KeyboardInterrupt):
        run_local(StudySpec(str(SMOKE), None, "object"), [0, 1], 1, seen.append)
    assert seen == []


def test_workers_fork_only_from_a_single_threaded_process() -> None:
    """Fork (the rig already imported) while this process has one thread; a forkserver otherwise."""
    import threading

    from rig.study.executor import _start_context

    if threading.active_count() == 1:
        assert _start_context().get_start_method() == "fork"
    release = threading.Event()
    other = threading.Thread(target=release.wait)
    other.start()
    try:
        assert _start_context().get_start_method() == "forkserver"
    finally:
        release.set()
        other.join()


# ----- the Dask path's chunks ----------------------------------------------------------------------


@pytest.mark.parametrize(("n", "threads"), [(1, 1), (5, 2), (64, 2), (200, 16), (3, 64)])
def test_seed_chunks_cover_every_seed_once_largest_first(n: int, threads: int) -> None:
    seeds = list(range(100, 100 + n))
    chunks = seed_chunks(seeds, threads)
    assert [s for chunk in chunks for s in chunk] == seeds
    sizes = [len(c) for c in chunks]
    assert sizes == sorted(sizes, reverse=True) and sizes[-1] == 1
    assert sizes[0] == math.ceil(n / (4 * threads))  # a quarter of a worker thread's share at first
    assert len(chunks) <= n


@pytest.mark.slow
def test_a_failed_dask_chunk_aborts_its_seeds_and_the_study_goes_on(monkeypatch: pytest.MonkeyPatch) -> None:
    distributed = pytest.importorskip("distributed")
    from rig.study import executor

    real = executor.run_seed

    def crashing(spec: StudySpec, seed: int) -> RunRecord:
        if seed == 0:
            raise RuntimeError("worker lost")  # run_seed itself never raises: as if the worker died
        return real(spec, seed)

    monkeypatch.setattr(executor, "run_seed", crashing)
    seen: list[int] = []
    with distributed.LocalCluster(processes=False, n_workers=1, threads_per_worker=1) as cluster:
        records = executor.run_dask(
            StudySpec(str(SMOKE), None, "object"),
            [0, 1, 2, 3, 4],
            cluster.scheduler_address,
            lambda r: seen.append(r.seed),
        )
    assert sorted(seen) == [0, 1, 2, 3, 4]
    first_chunk = executor.seed_chunks([0, 1, 2, 3, 4], 1)[0]
    assert first_chunk == [0, 1]
    by_seed = {r.seed: r for r in records}
    for seed in first_chunk:
        assert by_seed[seed].status == "aborted" and by_seed[seed].reason == "dask: RuntimeError: worker lost"
    assert all(by_seed[s].status == "completed" for s in (2, 3, 4))
