"""`rig study` of protocols with adaptive blocks: a case per series, trials used, coverage by stop."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pyarrow.parquet as pq
import pytest

from model.design import StopReason
from model.k_estimators import ESTIMATOR_NAMES
from rig.cli import main
from rig.inputs.files import parse_yaml
from rig.inputs.protocol import parse_protocol
from rig.study.executor import run_local
from rig.study.series import score_series
from rig.study.statistics import clopper_pearson, summarise
from rig.study.table import TABLE_NAME
from rig.study.worker import EstimatorResult, JointResult, RunRecord, StudySpec
from tests.helpers import adaptive_block, bare_protocol, shipped_block

REPO = Path(__file__).resolve().parents[1]
ADAPTIVE = REPO / "protocols" / "joint_estimation_adaptive.yaml"

# A fixed block and an adaptive one on joint 1, another adaptive block on joint 2: the first
# adaptive block stops on its (wide) target after its 3 minimum trials, the second can never reach
# its target and uses its budget of 4.
MIXED = bare_protocol(
    "mixed",
    [
        shipped_block("smoke", steps=None),
        adaptive_block(target_half_width_rel=0.5, min_trials=3, startup_trials=2, max_trials=6),
        adaptive_block(joint=2, target_half_width_rel=0.001, min_trials=3, startup_trials=2, max_trials=4),
    ],
    ramp={"max_force_n": 70.0},
    limits={"force_ceiling_n": 75.0},
)


def _mixed_protocol(tmp_path: Path) -> Path:
    path = tmp_path / "mixed.yaml"
    path.write_text(MIXED)
    return path


# ----- series ---------------------------------------------------------------------------------------


def _trials(*pairs: tuple[int, int]) -> list[Any]:
    """Stand-ins for TrialResults: (trial id, joint); `score_series` reads only the id."""
    return [SimpleNamespace(trial_id=trial_id, joint=joint) for trial_id, joint in pairs]


def _score_by_joint(trials: list[Any]) -> tuple[JointResult, ...]:
    """A stand-in scorer: one case per joint, its distances the ids of the trials it was given."""
    cases = []
    for joint in sorted({t.joint for t in trials}):
        ids = tuple(float(t.trial_id) for t in trials if t.joint == joint)
        cases.append(
            JointResult(joint, 0.16, 0.0, 0.085, ids, ids, (False,) * len(ids), len(ids), 0, 0, 1e-4, ())
        )
    return tuple(cases)


def test_without_adaptive_blocks_the_series_are_the_joints() -> None:
    trials = _trials((1, 1), (2, 2), (3, 1))
    assert score_series(trials, (), {}, _score_by_joint) == _score_by_joint(trials)


def test_each_adaptive_block_is_a_series_of_its_own_trials() -> None:
    protocol = parse_protocol(parse_yaml(MIXED, "p.yaml"), source="p.yaml", text=MIXED, joint_count=8)
    first, second = protocol.adaptive
    assert (first.trial_ids, second.trial_ids) == (range(3, 9), range(9, 13))
    trials = _trials((1, 1), (2, 1), (3, 1), (4, 1), (5, 1), (9, 2), (10, 2))
    cases = score_series(trials, protocol.adaptive, {first.block: StopReason.TARGET_REACHED}, _score_by_joint)
    assert [(c.joint, c.block, c.stop_reason, c.distances_m) for c in cases] == [
        (1, None, None, (1.0, 2.0)),  # the fixed trials of joint 1
        (1, 1, StopReason.TARGET_REACHED, (3.0, 4.0, 5.0)),
        (2, 2, None, (9.0, 10.0)),  # a block that never reported a stop (an aborted run)
    ]


# ----- summary --------------------------------------------------------------------------------------


def _adaptive_record(seed: int, trials: int, stop: StopReason, covered: bool) -> RunRecord:
    k_true = 0.2
    k_hat = k_true if covered else 0.3
    estimates = tuple(
        EstimatorResult(name, k_hat, k_hat - 0.01, k_hat + 0.01, 0.003, trials, 0, "auto", 0.0, 0.1)
        for name in ESTIMATOR_NAMES
    )
    joint = JointResult(
        1, k_true, 0.0, 0.1, (0.1,) * trials, (2.0,) * trials, (False,) * trials, trials, 0, 0, 1e-4,
        estimates, block=0, stop_reason=stop,
    )  # fmt: skip
    return RunRecord(seed, "completed", None, 24, trials, 0.1, (joint,))


def test_summary_gives_trial_quantiles_and_coverage_by_how_the_series_stopped() -> None:
    target, budget = StopReason.TARGET_REACHED, StopReason.BUDGET
    records = [
        _adaptive_record(0, 10, target, True),
        _adaptive_record(1, 12, target, False),
        _adaptive_record(2, 10, target, True),
        _adaptive_record(3, 24, budget, True),
        _adaptive_record(4, 14, target, True),
    ]
    e = summarise("p.yaml", range(5), records, ESTIMATOR_NAMES, 0.99).estimators["auto"]
    assert e.mean_trials == pytest.approx(14.0)
    assert e.median_trials == 12
    assert e.p90_trials == pytest.approx(14 + 0.6 * (24 - 14))  # linear between the 4th and 5th of 5
    assert e.coverage == pytest.approx(4 / 5)
    (reached, used_up) = e.coverage_by_stop
    assert (reached.stop_reason, reached.cases, reached.covered) == (target, 4, 3)
    assert reached.coverage == pytest.approx(0.75) and reached.coverage_ci == clopper_pearson(3, 4)
    assert (used_up.stop_reason, used_up.cases, used_up.covered, used_up.coverage) == (budget, 1, 1, 1.0)
    entry = e.as_json()["coverage_by_stop"]
    assert list(entry) == ["target_reached", "budget"]
    assert entry["target_reached"] == {
        "cases": 4,
        "coverage": 0.75,
        "coverage_ci": list(clopper_pearson(3, 4)),
    }


# ----- runs -----------------------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_scores_a_mixed_fixed_and_adaptive_protocol(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    protocol = _mixed_protocol(tmp_path)
    out = tmp_path / "out"
    code = main(["study", str(protocol), "--seeds", "0,1", "--jobs", "1", "--json", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    summary = json.loads(captured.out)
    assert summary["runs"] == 2 and summary["aborted"] == 0
    for entry in summary["estimators"].values():
        assert entry["median_trials"] == 2 + 3 + 4  # fixed 2, the first block stops at 3, the second uses 4
        assert {k: v["cases"] for k, v in entry["coverage_by_stop"].items()} == {
            "target_reached": 2,
            "budget": 2,
        }
    rows = [r for r in pq.read_table(out / TABLE_NAME).to_pylist() if r["estimator"] == "auto"]
    cases = sorted(
        (r["seed"], r["joint"], r["block"] or -1, r["stop_reason"], len(r["distances_m"])) for r in rows
    )
    assert cases == [
        (seed, joint, block, stop, n)
        for seed in (0, 1)
        for joint, block, stop, n in ((1, -1, None, 2), (1, 1, "target_reached", 3), (2, 2, "budget", 4))
    ]
    for r in rows:
        if r["block"] is None:
            assert sorted(r["distances_m"]) == [0.1, 0.2]
        elif r["stop_reason"] == "target_reached":  # the bound it stopped on is the one scored
            assert (r["k_high_kg_m"] - r["k_low_kg_m"]) / 2 <= 0.5 * r["k_kg_m"]


@pytest.mark.slow
@pytest.mark.subprocess
def test_worker_processes_give_the_in_process_adaptive_results(tmp_path: Path) -> None:
    spec = StudySpec(str(_mixed_protocol(tmp_path)), None, "object")
    alone = run_local(spec, [0, 1], 1, lambda r: None)
    in_processes = run_local(spec, [0, 1], 2, lambda r: None)

    def key(records: list[RunRecord]) -> list[tuple[object, ...]]:
        return sorted((r.seed, r.status, r.trials_completed, r.joints) for r in records)

    assert key(in_processes) == key(alone)
    assert all(j.stop_reason is not None for r in alone for j in r.joints if j.block is not None)


@pytest.mark.slow
def test_cli_runs_the_shipped_adaptive_protocol(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["study", str(ADAPTIVE), "--seeds", "0-2", "--jobs", "1"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "trials: mean / median / p90" in captured.out
    assert "coverage at the stop of the adaptive blocks" in captured.out
    records = run_local(StudySpec(str(ADAPTIVE), None, "object"), [0, 1, 2], 1, lambda r: None)
    for record in records:
        (case,) = record.joints
        used = case.n_slips + case.n_censored + case.n_excluded
        assert record.trials_completed == used <= 24
        assert (
            case.stop_reason is StopReason.BUDGET
            if used == 24
            else case.stop_reason is StopReason.TARGET_REACHED
        )
        assert not math.isnan(case.crlb_var)
