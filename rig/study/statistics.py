"""A study's statistics per estimator, and its table of every run x joint x estimator.

Each completed run contributes one case per estimated joint. Per estimator, over the cases where
it gave an estimate:

* coverage: the fraction whose bounds (at the study's level, 99 %) contain the true k, with the
  95 % Clopper-Pearson interval of that binomial proportion;
* bias_rel: mean of (k_hat - k) / k; rmse_rel: root mean square of the same;
* mse_over_crlb: mean of (k_hat - k)^2 / CRLB, the bound for the case's own design and true
  scatter (`rig.study.crlb`); 1 is the best an unbiased estimator can do;
* mean_trials, median_trials, p90_trials: the mean, median and 90th percentile (linear
  interpolation) of the number of trials the completed runs used (an adaptive design's cost);
* coverage_by_stop: for the cases of adaptive blocks, the coverage at the stop split by why the
  series stopped (target reached, budget used up, no safe distance), each with its 95 % interval:
  a series that stops on the target stops on a bound computed from the data that said stop, so
  its coverage is the one to watch (studies/README.md, adaptive_design.py).

Aborted runs are counted, not scored: a run that stopped early is not the design that was planned.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from model.design import StopReason
from rig.study.worker import RunRecord

CI_LEVEL = 0.95  # of the binomial interval around the measured coverage


@dataclass(frozen=True, slots=True)
class StopCoverage:
    """Coverage of one estimator over the adaptive series that stopped for one reason."""

    stop_reason: StopReason
    cases: int
    covered: int
    coverage_ci: tuple[float, float]

    @property
    def coverage(self) -> float:
        """The share of these cases whose bounds contain the true k."""
        return self.covered / self.cases if self.cases else math.nan

    def as_json(self) -> dict[str, Any]:
        """The entry of `coverage_by_stop` in `rig study --json`."""
        return {
            "cases": self.cases,
            "coverage": _finite(self.coverage),
            "coverage_ci": [_finite(self.coverage_ci[0]), _finite(self.coverage_ci[1])],
        }


@dataclass(frozen=True, slots=True)
class EstimatorSummary:
    """One estimator's performance over a study."""

    cases: int  # estimates made
    failures: int  # cases where it could not estimate (too few slips, ...)
    coverage: float
    coverage_ci: tuple[float, float]
    bias_rel: float
    rmse_rel: float
    mse_over_crlb: float
    mean_trials: float
    median_trials: float
    p90_trials: float
    coverage_by_stop: tuple[StopCoverage, ...] = ()  # adaptive cases only, in StopReason's order

    def as_json(self) -> dict[str, Any]:
        """The `rig study --json` entry of this estimator (JSON has no NaN: None instead)."""
        return {
            "coverage": _finite(self.coverage),
            "coverage_ci": [_finite(self.coverage_ci[0]), _finite(self.coverage_ci[1])],
            "bias_rel": _finite(self.bias_rel),
            "rmse_rel": _finite(self.rmse_rel),
            "mse_over_crlb": _finite(self.mse_over_crlb),
            "mean_trials": _finite(self.mean_trials),
            "median_trials": _finite(self.median_trials),
            "p90_trials": _finite(self.p90_trials),
            "coverage_by_stop": {c.stop_reason.value: c.as_json() for c in self.coverage_by_stop},
        }


@dataclass(frozen=True, slots=True)
class StudySummary:
    """What `rig study` reports."""

    protocol: str
    seeds: tuple[int, ...]
    runs: int
    aborted: int
    aborted_reasons: tuple[tuple[int, str], ...]  # (seed, reason)
    level: float
    estimators: dict[str, EstimatorSummary]

    def as_json(self) -> dict[str, Any]:
        """The `rig study --json` object: exactly protocol, seeds, runs, aborted, estimators."""
        return {
            "protocol": self.protocol,
            "seeds": list(self.seeds),
            "runs": self.runs,
            "aborted": self.aborted,
            "estimators": {name: e.as_json() for name, e in self.estimators.items()},
        }


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def clopper_pearson(successes: int, trials: int, level: float = CI_LEVEL) -> tuple[float, float]:
    """The exact (Clopper-Pearson) interval of a binomial proportion; (nan, nan) with no trials."""
    if trials <= 0:
        return math.nan, math.nan
    alpha = 1.0 - level
    low = 0.0 if successes == 0 else float(stats.beta.ppf(alpha / 2, successes, trials - successes + 1))
    high = (
        1.0
        if successes == trials
        else float(stats.beta.ppf(1 - alpha / 2, successes + 1, trials - successes))
    )
    return low, high


def summarise(
    protocol: str,
    seeds: Sequence[int],
    records: Sequence[RunRecord],
    estimator_names: Sequence[str],
    level: float,
) -> StudySummary:
    """The study's statistics from its run records (see the module docstring)."""
    # In seed order, whatever order the workers finished in: the sums come out the same to the last bit.
    completed = sorted((r for r in records if r.status == "completed"), key=lambda r: r.seed)
    aborted = sorted((r.seed, r.reason or "unknown") for r in records if r.status != "completed")
    trials = [r.trials_completed for r in completed]
    mean_trials = float(np.mean(trials)) if trials else math.nan
    median_trials = float(np.median(trials)) if trials else math.nan
    p90_trials = float(np.percentile(trials, 90)) if trials else math.nan
    summaries = {}
    for name in estimator_names:
        covered: list[bool] = []
        rel: list[float] = []
        over_crlb: list[float] = []
        by_stop: dict[StopReason, list[bool]] = {}
        failures = 0
        for run in completed:
            for joint in run.joints:
                est = next((e for e in joint.estimates if e.estimator == name), None)
                if est is None or est.error is not None or not math.isfinite(est.k):
                    failures += 1
                    continue
                truth = joint.k_true_kg_m
                covered.append(est.k_low <= truth <= est.k_high)
                if joint.stop_reason is not None:
                    by_stop.setdefault(joint.stop_reason, []).append(covered[-1])
                rel.append((est.k - truth) / truth)
                if math.isfinite(joint.crlb_var) and joint.crlb_var > 0:
                    over_crlb.append((est.k - truth) ** 2 / joint.crlb_var)
        n = len(covered)
        hits = sum(covered)
        summaries[name] = EstimatorSummary(
            cases=n,
            failures=failures,
            coverage=hits / n if n else math.nan,
            coverage_ci=clopper_pearson(hits, n),
            bias_rel=float(np.mean(rel)) if rel else math.nan,
            rmse_rel=float(np.sqrt(np.mean(np.square(rel)))) if rel else math.nan,
            mse_over_crlb=float(np.mean(over_crlb)) if over_crlb else math.nan,
            mean_trials=mean_trials,
            median_trials=median_trials,
            p90_trials=p90_trials,
            coverage_by_stop=tuple(
                StopCoverage(
                    reason,
                    len(by_stop[reason]),
                    sum(by_stop[reason]),
                    clopper_pearson(sum(by_stop[reason]), len(by_stop[reason])),
                )
                for reason in StopReason
                if reason in by_stop
            ),
        )
    return StudySummary(
        protocol=protocol,
        seeds=tuple(seeds),
        runs=len(records),
        aborted=len(aborted),
        aborted_reasons=tuple(aborted),
        level=level,
        estimators=summaries,
    )
