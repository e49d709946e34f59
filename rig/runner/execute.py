"""One `rig run` invocation: run ids, the journal, the MCAP file, the session, and the final report.

`prepare_run` validates everything (protocol, rig config, limits, resume consistency, the run id
and the `--out` directory) before any device is opened, and locks the run against other
invocations; invalid input raises `InputError` and nothing but the lock file is written.
`execute_run` then opens a new MCAP file for this invocation, writes the metadata and
attachments, runs the remaining trials through `TrialRunner`, saves the journal and estimates,
releases the lock, and returns a `RunReport` whose `as_json()` is the `rig run --json` object
(docs/design.md §5).
"""

from __future__ import annotations

import contextlib
import json
import platform
import re
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rig
from model.fit import FitSummary
from model.fit_keys import EstimateSummary
from model.payload_errors import PayloadErrorStats
from rig.errors import ExitCode, InputError
from rig.hw.session import RigSession
from rig.hw.usb_latency import DEFAULT_SYSFS_ROOT
from rig.inputs.files import atomic_write_text, check_out_dir
from rig.inputs.protocol import Protocol, TrialPlan, for_loadcell_rate, load_protocol
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, RigConfig, load_rig_config, nominal_loadcell_rate_hz
from rig.log.format import schemas
from rig.log.live.publisher import LivePublisher
from rig.log.writing.writer import LogWriteError, RunLogger
from rig.records import JointCapacity, LogLevel, LogMessage, TrialResult
from rig.runner.file_changes import describe_changes
from rig.runner.journal import RunJournal, content_hash
from rig.runner.limits import check_limits
from rig.runner.planning import AdaptiveSummary, TrialSchedule
from rig.runner.progress import ProgressReporter
from rig.runner.results import percentage_error_stats
from rig.runner.rig_to_run import GroundTruth, RigToRun, TruthSnapshot
from rig.runner.run_estimates import RunEstimator, load_estimates_file
from rig.runner.runlock import RunLock
from rig.runner.trial_runner import RunOutcome, TrialRunner
from rig.safety.interrupts import interrupts_held
from rig.safety.safe_state import enter_safe_state
from rig.vocabulary import RigKind

# Run ids name files in --out (RUN_ID.mcap, RUN_ID.partN.mcap, RUN_ID.journal.json, ...): no path
# separators, no leading dot, bounded length, and no `.partN` ending, which a resumed run's logs use.
RUN_ID_MAX_CHARS = 100
_RUN_ID = re.compile(rf"[A-Za-z0-9][A-Za-z0-9._-]{{0,{RUN_ID_MAX_CHARS - 1}}}")
_PART_SUFFIX = re.compile(r"\.part[0-9]+")
_UNSAFE_IN_NAME = re.compile(r"[^A-Za-z0-9_-]+")
_INTERRUPTED = "interrupted by the operator"


@dataclass
class RunRequest:
    """What the user asked for on the command line."""

    protocol_path: Path | None  # None only with `resume`: the journal's
    rig_path: Path | None  # None: the built-in simulated rig, or with `resume` the journal's rig
    out_dir: Path
    seed: int
    realtime: bool = False
    run_id: str | None = None
    resume: str | None = None
    sysfs_root: Path = DEFAULT_SYSFS_ROOT  # where a hardware rig's USB latency timers are read


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
    truth: TruthSnapshot | None = None  # a simulated rig's, beside its session (rig_to_run.py)
    safe_state_verified: bool = True
    resumable: bool = False  # trials are left to run (`--resume` continues); False once all are done
    design: tuple[AdaptiveSummary, ...] = ()  # adaptive blocks: where each stands, why it stopped
    # The protocol's estimator's fit with the paper's beside it (None before 2 slips).
    estimate_detail: EstimateSummary | None = None

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
            "estimate": _estimate_json(self.estimate, self.estimate_detail),
            "joints": [j.to_json() for j in self.joints],
        }
        if self.design:
            out["design"] = [d.to_json() for d in self.design]
        if self.percentage_errors is not None:
            out["percentage_errors"] = self.percentage_errors.to_dict()
        if self.truth is not None:
            out["truth"] = self.truth.to_json(with_trials=False)
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
    remaining: list[TrialPlan]  # the fixed trials not done yet (adaptive blocks choose theirs as they run)
    log_path: Path  # this invocation's MCAP file
    estimates_path: Path
    lock: RunLock | None = None

    def release(self) -> None:
        """Give up the run's lock (`execute_run` does it when it returns); idempotent."""
        if self.lock is not None:
            self.lock.release()


def prepare_run(request: RunRequest, *, dry_run: bool = False) -> PreparedRun:
    """Validate the request, lock the run, and load or create its journal; raises InputError on bad input.

    The lock (`OUT/RUN_ID.lock`) is held until `execute_run` returns or `PreparedRun.release()`.
    A dry run validates the same and writes nothing: no directory, no lock.
    """
    if request.resume is not None:
        run_id = _check_run_id(request.resume, "--resume")
        check_out_dir(request.out_dir, must_exist=True)
        lock = None if dry_run else _lock_run(request.out_dir, run_id)
        with _released_on_error(lock):
            protocol, config, journal = _resumed_journal(request, run_id)
            return _prepared(request, protocol, config, journal, lock)
    if request.protocol_path is None:
        raise InputError("PROTOCOL: required to start a run (`rig run --resume RUN_ID` continues one)")
    config = load_rig_config(request.rig_path)
    protocol = load_protocol(
        request.protocol_path,
        seed=request.seed,
        joint_count=config.article.joint_count,
        joints_from=config.joints_from,
    )
    check_limits(protocol, config)
    run_id = (
        _check_run_id(request.run_id, "--run-id") if request.run_id is not None else _new_run_id(protocol)
    )
    check_out_dir(request.out_dir)
    if not dry_run:
        _make_out_dir(request.out_dir)
    lock = None if dry_run else _lock_run(request.out_dir, run_id)
    with _released_on_error(lock):
        path = _in_out_dir(request.out_dir, RunJournal.path_for(request.out_dir, run_id))
        if path.exists():
            raise InputError(
                f"{path}: run {run_id} already exists; use --resume {run_id} or another --run-id"
            )
        journal = RunJournal(
            path=path,
            run_id=run_id,
            # Absolute, so that `--resume RUN_ID` finds them from any directory.
            protocol_path=str(request.protocol_path.absolute()),
            protocol_hash=content_hash(protocol.text),
            rig_path=str(Path(config.source).absolute()),
            rig_hash=content_hash(config.text),
            seed=request.seed,
            planned_trials=protocol.planned_trial_ids,
            rig_builtin=request.rig_path is None,
            protocol_text=protocol.text,
            rig_text=config.text,
        )
        return _prepared(request, protocol, config, journal, lock)


def _resumed_journal(request: RunRequest, run_id: str) -> tuple[Protocol, RigConfig, RunJournal]:
    """The journal of run `run_id`, its protocol and rig config, checked to be the same files by content.

    PROTOCOL and `--rig` left out are the journal's files; given, they may be elsewhere (a copy or a
    move) but must have the same content. A changed file is named with the values that changed.
    """
    journal = RunJournal.load(_in_out_dir(request.out_dir, RunJournal.path_for(request.out_dir, run_id)))
    if journal.status == "completed":
        raise InputError(f"{journal.path}: run {run_id} is already completed; nothing to resume")
    config = load_rig_config(_resumed_file(request.rig_path, journal, "rig"))
    protocol_path = _resumed_file(request.protocol_path, journal, "protocol")
    assert protocol_path is not None
    protocol = load_protocol(
        protocol_path,
        seed=journal.seed,
        joint_count=config.article.joint_count,
        joints_from=config.joints_from,
    )
    # By content, not path: a protocol moved or copied unchanged resumes; an edited one does not.
    if journal.protocol_hash != content_hash(protocol.text):
        changes = describe_changes(journal.protocol_text, protocol.text, str(protocol_path))
        raise InputError(
            f"{protocol_path}: changed since run {run_id} started (it used {journal.protocol_path}"
            + (f": {changes}" if changes else ", whose content differs")
            + "); refusing to resume"
        )
    if journal.rig_hash != content_hash(config.text):
        changes = describe_changes(journal.rig_text, config.text, str(config.source))
        raise InputError(
            f"{config.source}: rig config changed since run {run_id} started"
            + (f" ({changes})" if changes else "")
            + "; refusing to resume"
        )
    check_limits(protocol, config)
    return protocol, config, journal


def _resumed_file(given: Path | None, journal: RunJournal, which: str) -> Path | None:
    """The file a resume uses: the one given, else the journal's (None: the built-in simulated rig)."""
    if given is not None:
        return given
    if which == "rig" and (journal.rig_builtin or journal.rig_path == str(DEFAULT_RIG_CONFIG)):
        return None
    recorded = Path(journal.rig_path if which == "rig" else journal.protocol_path)
    if not recorded.is_file():
        option = "--rig CONFIG" if which == "rig" else "PROTOCOL"
        raise InputError(
            f"{recorded}: the {which} file run {journal.run_id} started with (its journal says so) is not "
            f"there; give {option}, a file with the same content"
        )
    return recorded


def _prepared(
    request: RunRequest, protocol: Protocol, config: RigConfig, journal: RunJournal, lock: RunLock | None
) -> PreparedRun:
    # The detector's rate-dependent defaults for this rig's load cell; the logged protocol metadata
    # carries them, so replay detects with them.
    protocol = for_loadcell_rate(protocol, nominal_loadcell_rate_hz(config))
    prior = None
    if protocol.estimates_from not in (None, "run"):
        prior = load_estimates_file(protocol.estimates_from)
    estimator = RunEstimator(config.article, prior_summary=prior, estimator=protocol.estimator)
    estimator.replay(journal.completed)
    done = journal.completed_ids
    remaining = [t for t in protocol.trials if t.trial_id not in done]
    invocation = journal.invocations + 1
    suffix = "" if invocation == 1 else f".part{invocation}"
    out = request.out_dir
    log_path = _in_out_dir(out, out / f"{journal.run_id}{suffix}.mcap")
    if log_path.exists():
        raise InputError(f"{log_path}: exists; refusing to overwrite a log")
    estimates_path = _in_out_dir(out, out / f"{journal.run_id}.estimates.json")
    return PreparedRun(
        request,
        protocol,
        config,
        journal.run_id,
        journal,
        estimator,
        remaining,
        log_path,
        estimates_path,
        lock=lock,
    )


def execute_run(
    prepared: PreparedRun,
    rig: RigToRun,
    progress: ProgressReporter,
    *,
    live: LivePublisher | None = None,
) -> RunReport:
    """Run the remaining trials on `rig`'s session, write the log, journal and estimates, release the lock.

    A simulated rig's truth goes into the log's `sim_truth` metadata and the report; its log limit,
    if any, caps the log file (rig_to_run.py).

    With `live`, every logged message is also offered to the live view (which the caller closes; its
    counts of published and dropped messages end the run's `/rig/log`).

    Ctrl-C and SIGTERM stop the trials (the runner ends in the safe state); while the log and journal
    are set up, and from the safe state on while they are finished, they are held, so the journal
    always ends with the run's status and the report is returned (docs/design.md §6).
    """
    try:
        return _execute(prepared, rig, progress, live)
    finally:
        prepared.release()


def _execute(
    prepared: PreparedRun, rig: RigToRun, progress: ProgressReporter, live: LivePublisher | None
) -> RunReport:
    protocol, config, journal = prepared.protocol, prepared.config, prepared.journal
    session = rig.session
    log_path = prepared.log_path
    outcome: RunOutcome | None = None
    logger: RunLogger | None = None
    log_error: LogWriteError | None = None
    schedule: TrialSchedule | None = None
    try:
        with interrupts_held() as early:
            journal.invocations += 1
            journal.logs.append(str(log_path))
            journal.status = "running"
            journal.save()
            logger = RunLogger(log_path, clock=session.clock, max_file_bytes=rig.log_limit_bytes, live=live)
            _write_metadata(logger, prepared, session)
            progress.start(journal.run_id, len(protocol.planned_trial_ids), len(journal.completed))
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
            schedule = TrialSchedule(protocol, config, journal, runner.announce)
        try:
            if early:
                raise KeyboardInterrupt
            outcome = runner.run(schedule)
        except KeyboardInterrupt:
            # Before the runner began (nothing connected yet), or just after its safe state.
            if not runner.connected:
                with interrupts_held():
                    enter_safe_state(session, lambda: None)
            outcome = RunOutcome(ExitCode.INTERRUPTED, "interrupted", _INTERRUPTED)
    finally:
        with interrupts_held():
            progress.stop()
            if logger is not None:
                log_error = _finish_log(logger, session if outcome is not None else None, rig.truth)
    if log_error is not None and outcome.exit_code == ExitCode.OK:  # the rig is safe; the log is not whole
        reason = f"LogWriteError: {log_error}"
        verified = outcome.safe_state_verified
        outcome = RunOutcome(ExitCode.FAULT, "faulted", reason, outcome.new_results, verified)
    with interrupts_held():
        return _finish(prepared, rig.truth, outcome, schedule)


def _finish_log(
    logger: RunLogger, session: RigSession | None, truth: GroundTruth | None
) -> LogWriteError | None:
    """Add the simulator's truth (every trial's hidden draws) and finish the file; the error, if any.

    A log that cannot be written does not hide how the run ended: the error is returned, not raised.
    """
    try:
        if logger.live is not None:
            stats = logger.live.close()
            logger.live = None
            now = session.clock.time_ns() if session is not None else time.time_ns()
            level = LogLevel.WARNING if stats.dropped or stats.slow_client_events else LogLevel.INFO
            logger.log(schemas.LOG, now, LogMessage(now, level, stats.text()).to_payload())
        if session is not None and truth is not None:
            truth_json = json.dumps(truth.snapshot().to_json(), allow_nan=False)
            logger.add_metadata("sim_truth", {"json": truth_json})
        logger.finish()
    except LogWriteError as exc:
        with contextlib.suppress(LogWriteError):
            logger.finish()
        return exc
    return None


def _finish(
    prepared: PreparedRun,
    truth: GroundTruth | None,
    outcome: RunOutcome,
    schedule: TrialSchedule | None = None,
) -> RunReport:
    journal, log_path, estimates_path = prepared.journal, prepared.log_path, prepared.estimates_path
    journal.status = outcome.status
    journal.save()
    summary = prepared.estimator.summary()
    detail = prepared.estimator.estimate_summary()
    joints = prepared.estimator.joint_estimates()
    estimates = {
        "run_id": journal.run_id,
        "estimate": _estimate_json(summary, detail),
        "joints": [j.to_json() for j in joints],
    }
    atomic_write_text(estimates_path, json.dumps(estimates, indent=1) + "\n")
    return RunReport(
        run_id=journal.run_id,
        log=str(log_path),
        logs=list(journal.logs),
        trials=list(journal.completed),
        completed=len(journal.completed),
        planned=len(prepared.protocol.planned_trial_ids),
        aborted=outcome.exit_code != ExitCode.OK,
        reason=outcome.reason,
        exit_code=outcome.exit_code,
        safe_state_verified=outcome.safe_state_verified,
        resumable=journal.status != "completed",
        estimate=summary,
        percentage_errors=percentage_error_stats(journal.completed),
        joints=joints,
        truth=truth.snapshot() if truth is not None else None,
        design=tuple(schedule.summaries.values()) if schedule is not None else (),
        estimate_detail=detail,
    )


def _estimate_json(summary: FitSummary | None, detail: EstimateSummary | None) -> dict[str, Any] | None:
    """The run's estimate as `rig fit --json` prints it (with the paper's fit), or the prior's keys."""
    if detail is not None:
        return detail.as_json()
    return summary.as_json() if summary is not None else None


def _write_metadata(logger: RunLogger, prepared: PreparedRun, session: RigSession) -> None:
    request = prepared.request
    logger.add_metadata(
        "session",
        {
            "software": f"rig {rig.__version__}",
            "python": platform.python_version(),
            "host": socket.gethostname(),
            "seed": str(prepared.journal.seed),
            "clock": "realtime" if request.realtime or session.kind == RigKind.HARDWARE else "virtual",
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
    if not _RUN_ID.fullmatch(run_id) or _PART_SUFFIX.search(run_id):
        raise InputError(
            f"{flag} {run_id!r}: allowed: 1-{RUN_ID_MAX_CHARS} letters, digits, '.', '_', '-', starting "
            "with a letter or digit, not ending in '.partN'"
        )
    return run_id


def _new_run_id(protocol: Protocol) -> str:
    """UTC start time + the protocol's name, made safe: only letters, digits, '_', '-'; bounded length."""
    stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
    name = _UNSAFE_IN_NAME.sub("_", protocol.name).strip("_-")
    name = name[: RUN_ID_MAX_CHARS - len(stamp) - 1].rstrip("_-") or "run"
    return f"{stamp}-{name}"


def _make_out_dir(out_dir: Path) -> None:
    """Make the (checked) `--out` directory of a new run."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out {out_dir}: cannot create the directory ({exc.strerror or exc})") from None
    check_out_dir(out_dir)  # made by another process since, as something else


def _lock_run(out_dir: Path, run_id: str) -> RunLock:
    path = _in_out_dir(out_dir, out_dir / f"{run_id}.lock")
    try:
        return RunLock.acquire(path, run_id)
    except OSError as exc:  # e.g. a read-only file system, which os.access does not see for root
        raise InputError(f"--out {out_dir}: cannot write there ({exc.strerror or exc})") from None


def _in_out_dir(out_dir: Path, path: Path) -> Path:
    """`path`, checked to resolve to a file directly inside `out_dir` (no symbolic link out of it)."""
    if path.resolve().parent != out_dir.resolve():
        raise InputError(f"{path}: would be written outside --out {out_dir}; refusing")
    return path


@contextmanager
def _released_on_error(lock: RunLock | None) -> Iterator[None]:
    try:
        yield
    except BaseException:
        if lock is not None:
            lock.release()
        raise
