"""One `rig run` invocation: run ids, the journal, the MCAP file, the session, and the final report.

`start_run` validates everything (protocol, rig config, limits, resume consistency) before any
device is opened; invalid input raises `InputError` and nothing is written. It then builds the
session (simulated or hardware), opens a new MCAP file for this invocation, writes the metadata
and attachments, runs the remaining trials through `TrialRunner`, and returns a `RunReport`
whose `as_json()` is the `rig run --json` object (docs/design.md §5).
"""

from __future__ import annotations

import contextlib
import json
import platform
import re
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rig
from model.fit import FitSummary
from model.payload_errors import PayloadErrorStats
from rig.errors import ExitCode, InputError
from rig.files import atomic_write_text
from rig.hw.session import RigSession
from rig.log.records import JointCapacity, TrialResult
from rig.log.writer import LogWriteError, RunLogger
from rig.protocol import Protocol, TrialPlan, load_protocol
from rig.rig_config import RigConfig, load_rig_config
from rig.runner.estimation import RunEstimator, load_estimates_file
from rig.runner.journal import RunJournal, content_hash
from rig.runner.limits import check_limits
from rig.runner.progress import ProgressReporter
from rig.runner.results import percentage_error_stats
from rig.runner.trial_runner import RunOutcome, TrialRunner

_RUN_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


@dataclass
class RunRequest:
    """What the user asked for on the command line."""

    protocol_path: Path
    rig_path: Path | None
    out_dir: Path
    seed: int
    realtime: bool = False
    run_id: str | None = None
    resume: str | None = None


@dataclass
class RunReport:
    """The result of one invocation, over the whole run (resumed parts included)."""

    run_id: str
    log: str
    logs: list[str]
    trials: list[TrialResult]
    completed: int
    planned: int
    aborted: bool
    reason: str | None
    exit_code: ExitCode
    estimate: FitSummary | None
    percentage_errors: PayloadErrorStats | None
    joints: tuple[JointCapacity, ...] = ()
    truth: dict[str, Any] | None = None
    safe_state_verified: bool = True

    def as_json(self) -> dict[str, Any]:
        """The `rig run --json` object (docs/design.md §5)."""
        out: dict[str, Any] = {
            "run_id": self.run_id,
            "log": self.log,
            "logs": self.logs,
            "trials": [t.to_json() for t in self.trials],
            "completed": self.completed,
            "planned": self.planned,
            "aborted": self.aborted,
            "reason": self.reason,
            "safe_state_verified": self.safe_state_verified,
            "estimate": self.estimate.as_json() if self.estimate is not None else None,
            "joints": [j.to_json() for j in self.joints],
        }
        if self.percentage_errors is not None:
            out["percentage_errors"] = self.percentage_errors.to_dict()
        if self.truth is not None:
            out["truth"] = self.truth
        return out


@dataclass
class PreparedRun:
    """Everything validated before a device is touched."""

    request: RunRequest
    protocol: Protocol
    config: RigConfig
    run_id: str
    journal: RunJournal
    estimator: RunEstimator
    remaining: list[TrialPlan]


def prepare_run(request: RunRequest) -> PreparedRun:
    """Validate the request and load or create the journal; raises InputError on bad input."""
    config = load_rig_config(request.rig_path)
    journal: RunJournal | None
    if request.resume is not None:
        run_id = _check_run_id(request.resume, "--resume")
        journal = RunJournal.load(RunJournal.path_for(request.out_dir, run_id))
        seed = journal.seed
        if journal.status == "completed":
            raise InputError(f"{journal.path}: run {run_id} is already completed; nothing to resume")
        if Path(journal.protocol_path).resolve() != request.protocol_path.resolve():
            raise InputError(
                f"--resume {run_id}: the run used protocol {journal.protocol_path}, "
                f"not {request.protocol_path}"
            )
    else:
        seed = request.seed
        journal = None
    protocol = load_protocol(request.protocol_path, seed=seed, joint_count=config.article.joint_count)
    check_limits(protocol, config)
    protocol_hash = content_hash(protocol.text)
    rig_hash = content_hash(config.text)
    if journal is not None:
        if journal.protocol_hash != protocol_hash:
            raise InputError(
                f"{request.protocol_path}: changed since run {journal.run_id} started; refusing to resume"
            )
        if journal.rig_hash != rig_hash:
            raise InputError(
                f"{config.source}: rig config changed since run {journal.run_id} started; refusing to resume"
            )
    else:
        run_id = _check_run_id(request.run_id, "--run-id") if request.run_id else _new_run_id(protocol)
        path = RunJournal.path_for(request.out_dir, run_id)
        if path.exists():
            raise InputError(
                f"{path}: run {run_id} already exists; use --resume {run_id} or another --run-id"
            )
        journal = RunJournal(
            path=path,
            run_id=run_id,
            protocol_path=str(request.protocol_path),
            protocol_hash=protocol_hash,
            rig_path=str(config.source),
            rig_hash=rig_hash,
            seed=seed,
            planned_trials=[t.trial_id for t in protocol.trials],
        )
    prior = None
    if protocol.estimates_from not in (None, "run"):
        prior = load_estimates_file(protocol.estimates_from)
    estimator = RunEstimator(config.article, prior_summary=prior)
    estimator.replay(journal.completed)
    done = journal.completed_ids
    remaining = [t for t in protocol.trials if t.trial_id not in done]
    return PreparedRun(request, protocol, config, journal.run_id, journal, estimator, remaining)


def execute_run(prepared: PreparedRun, session: RigSession, progress: ProgressReporter) -> RunReport:
    """Run the remaining trials on `session` and write the log, journal and estimates."""
    request, protocol, config, journal = (
        prepared.request,
        prepared.protocol,
        prepared.config,
        prepared.journal,
    )
    request.out_dir.mkdir(parents=True, exist_ok=True)
    journal.invocations += 1
    suffix = "" if journal.invocations == 1 else f".part{journal.invocations}"
    log_path = request.out_dir / f"{journal.run_id}{suffix}.mcap"
    if log_path.exists():
        raise InputError(f"{log_path}: exists; refusing to overwrite a log")
    journal.logs.append(str(log_path))
    journal.status = "running"
    journal.save()
    logger = RunLogger(log_path, clock=session.clock, max_file_bytes=session.log_limit_bytes)
    try:
        _write_metadata(logger, prepared, session)
        progress.start(journal.run_id, len(protocol.trials), len(journal.completed))
        runner = TrialRunner(
            protocol=protocol,
            config=config,
            session=session,
            logger=logger,
            journal=journal,
            estimator=prepared.estimator,
            progress=progress,
            line_stiffness_n_per_m=config.line_stiffness_n_per_m,
        )
        outcome = runner.run(prepared.remaining)
    finally:
        progress.stop()
        log_error: LogWriteError | None = None
        try:
            if session.truth is not None:  # at the end, so it includes every trial's hidden draws
                truth_json = json.dumps(session.truth.detail(), allow_nan=False)
                logger.add_metadata("sim_truth", {"json": truth_json})
            logger.finish()
        except LogWriteError as exc:  # the run's own outcome says what stopped it; the rig is safe
            log_error = exc
            with contextlib.suppress(LogWriteError):
                logger.finish()
    if log_error is not None and outcome.exit_code == ExitCode.OK:  # the rig is safe; the log is not whole
        reason = f"LogWriteError: {log_error}"
        outcome = RunOutcome(
            ExitCode.FAULT, "faulted", reason, outcome.new_results, outcome.safe_state_verified
        )
    journal.status = outcome.status
    journal.save()
    summary = prepared.estimator.summary()
    joints = prepared.estimator.joint_estimates()
    estimates_path = request.out_dir / f"{journal.run_id}.estimates.json"
    estimates = {
        "run_id": journal.run_id,
        "estimate": summary.as_json() if summary is not None else None,
        "joints": [j.to_json() for j in joints],
    }
    atomic_write_text(estimates_path, json.dumps(estimates, indent=1) + "\n")
    truth = session.truth.summary() if session.truth is not None else None
    return RunReport(
        run_id=journal.run_id,
        log=str(log_path),
        logs=list(journal.logs),
        trials=list(journal.completed),
        completed=len(journal.completed),
        planned=len(protocol.trials),
        aborted=outcome.exit_code != ExitCode.OK,
        reason=outcome.reason,
        exit_code=outcome.exit_code,
        safe_state_verified=outcome.safe_state_verified,
        estimate=summary,
        percentage_errors=percentage_error_stats(journal.completed),
        joints=joints,
        truth=truth,
    )


def _write_metadata(logger: RunLogger, prepared: PreparedRun, session: RigSession) -> None:
    request = prepared.request
    logger.add_metadata(
        "session",
        {
            "software": f"rig {rig.__version__}",
            "python": platform.python_version(),
            "host": socket.gethostname(),
            "seed": str(prepared.journal.seed),
            "clock": "realtime" if request.realtime or session.kind == "hardware" else "virtual",
            "run_id": prepared.run_id,
            "invocation": str(prepared.journal.invocations),
            "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        },
    )
    logger.add_metadata("protocol", prepared.protocol.as_metadata())
    logger.add_metadata("rig", prepared.config.as_metadata())
    logger.add_attachment(prepared.protocol.source.name, "application/yaml", prepared.protocol.text.encode())
    logger.add_attachment(prepared.config.source.name, "application/yaml", prepared.config.text.encode())
    for name, media_type, data in session.attachments:
        logger.add_attachment(name, media_type, data)


def _check_run_id(run_id: str, flag: str) -> str:
    if not _RUN_ID.match(run_id):
        raise InputError(f"{flag} {run_id!r}: allowed: letters, digits, '.', '_', '-' (1-100 characters)")
    return run_id


def _new_run_id(protocol: Protocol) -> str:
    return time.strftime("%Y%m%dT%H%M%S", time.gmtime()) + f"-{protocol.name}"
