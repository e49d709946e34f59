"""One run invocation: run ids, the journal, the run's sinks, and the final report.

`validate_run` checks everything (`--out`, protocol, rig config, limits, resume consistency, the
run id) once, before any device is opened, and writes nothing; `claim_run` then makes `--out` and
locks the run against other invocations (`prepare_run` is the two in one). Invalid input raises
`InputError`, and nothing but the directory and the lock file is written.
`execute_run` is the one way a run happens: it runs the remaining trials through `TrialRunner`,
emitting the run to its sinks (`rig.runner.sinks`: the MCAP file unless `log_file=False`, and those
the caller gives: the progress display, the live view), saves the journal and estimates, releases
the lock, and returns a `RunReport` whose `as_json()` is the `rig run --json` object
(docs/design.md §5).
"""

from __future__ import annotations

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
from rig.log.writing.writer import LogWriteError
from rig.records import JointCapacity, TrialResult
from rig.runner.file_changes import describe_changes
from rig.runner.journal import RunJournal, content_hash
from rig.runner.limits import check_limits
from rig.runner.planning import AdaptiveSummary, TrialSchedule
from rig.runner.results import percentage_error_stats
from rig.runner.rig_to_run import GroundTruth, RigToRun, TruthSnapshot
from rig.runner.run_estimates import RunEstimator, load_estimates_file
from rig.runner.runlock import RunLock
from rig.runner.sinks import McapSink, RunSink
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
    journal_hash: str | None  # a resumed run's journal file as validated (None: a new run)
    lock: RunLock | None = None  # taken by `claim_run`

    def release(self) -> None:
        """Give up the run's lock (`execute_run` does it when it returns); idempotent."""
        if self.lock is not None:
            self.lock.release()


def prepare_run(request: RunRequest, *, dry_run: bool = False) -> PreparedRun:
    """Validate the request, then (unless `dry_run`) claim the run (`claim_run`); InputError on bad input.

    A dry run validates the same and writes nothing: no directory, no lock.
    """
    prepared = validate_run(request)
    return prepared if dry_run else claim_run(prepared)


def validate_run(request: RunRequest) -> PreparedRun:
    """Check everything the run needs (the protocol parsed and limit-checked once); write nothing.

    The result holds no lock yet: `claim_run` makes `--out` and takes it. InputError on bad input.
    """
    check_out_dir(request.out_dir, must_exist=request.resume is not None)
    if request.resume is not None:
        run_id = _check_run_id(request.resume, "--resume")
        protocol, config, journal, journal_hash = _resumed_journal(request, run_id)
        return _prepared(request, protocol, config, journal, journal_hash)
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
    path = _new_journal_path(request.out_dir, run_id)
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
    return _prepared(request, protocol, config, journal, None)


def claim_run(prepared: PreparedRun) -> PreparedRun:
    """Make `--out` if needed and lock the run (`OUT/RUN_ID.lock`) against other invocations.

    The lock is held until `execute_run` returns or `PreparedRun.release()`. Under it, what another
    invocation could have changed since `validate_run` is checked again: a new run's journal and
    this invocation's log must still not exist, a resumed run's journal must be the one validated.
    """
    out = prepared.request.out_dir
    if prepared.request.resume is None:
        _make_out_dir(out)
    lock = _lock_run(out, prepared.run_id)
    with _released_on_error(lock):
        journal_path = prepared.journal.path
        if prepared.journal_hash is None:
            _new_journal_path(out, prepared.run_id)
        elif _file_hash(journal_path) != prepared.journal_hash:
            raise InputError(
                f"{journal_path}: run {prepared.run_id} changed while this invocation started (another "
                "invocation worked on it); try again"
            )
        if prepared.log_path.exists():
            raise InputError(f"{prepared.log_path}: exists; refusing to overwrite a log")
    prepared.lock = lock
    return prepared


def _new_journal_path(out_dir: Path, run_id: str) -> Path:
    """Where a new run's journal goes; InputError if the run exists already."""
    path = _in_out_dir(out_dir, RunJournal.path_for(out_dir, run_id))
    if path.exists():
        raise InputError(f"{path}: run {run_id} already exists; use --resume {run_id} or another --run-id")
    return path


def _file_hash(path: Path) -> str | None:
    """The content hash of the file at `path` (None if it cannot be read: `RunJournal.load` says why)."""
    try:
        return content_hash(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError):
        return None


def _resumed_journal(request: RunRequest, run_id: str) -> tuple[Protocol, RigConfig, RunJournal, str | None]:
    """The journal of run `run_id` (and its file's hash), its protocol and rig config, checked by content.

    PROTOCOL and `--rig` left out are the journal's files; given, they may be elsewhere (a copy or a
    move) but must have the same content. A changed file is named with the values that changed.
    """
    path = _in_out_dir(request.out_dir, RunJournal.path_for(request.out_dir, run_id))
    journal_hash = _file_hash(path)  # before it is read: `claim_run` sees any change after this
    journal = RunJournal.load(path)
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
    return protocol, config, journal, journal_hash


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
    request: RunRequest, protocol: Protocol, config: RigConfig, journal: RunJournal, journal_hash: str | None
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
        journal_hash,
    )


def execute_run(prepared: PreparedRun, rig: RigToRun, *sinks: RunSink, log_file: bool = True) -> RunReport:
    """Run the remaining trials on `rig`'s session, emitting the run to `sinks`; release the lock.

    The one way a run happens (`rig run`, `rig study`'s workers, the studies and tests). An
    unclaimed run is claimed first (`claim_run`). With `log_file`, the MCAP file
    `prepared.log_path` is the first sink (`McapSink`); `rig study` runs without it. The journal
    and the estimates file are written either way.

    A simulated rig's truth goes into the `sim_truth` metadata and the report; its log limit, if
    any, caps the log file (rig_to_run.py).

    Ctrl-C and SIGTERM stop the trials (the runner ends in the safe state); while the sinks are set
    up, and from the safe state on while they are finished, they are held, so the journal always
    ends with the run's status and the report is returned (docs/design.md §6).
    """
    if prepared.lock is None:
        claim_run(prepared)
    try:
        return _execute(prepared, rig, sinks, log_file)
    finally:
        prepared.release()


def _execute(prepared: PreparedRun, rig: RigToRun, given: tuple[RunSink, ...], log_file: bool) -> RunReport:
    protocol, config, journal = prepared.protocol, prepared.config, prepared.journal
    session = rig.session
    outcome: RunOutcome | None = None
    log_error: LogWriteError | None = None
    schedule: TrialSchedule | None = None
    sinks: tuple[RunSink, ...] = given
    try:
        with interrupts_held() as early:
            journal.invocations += 1
            journal.logs.append(str(prepared.log_path))
            journal.status = "running"
            journal.save()
            if log_file:
                mcap = McapSink(prepared.log_path, session.clock, max_file_bytes=rig.log_limit_bytes)
                sinks = (mcap, *given)
            for sink in sinks:
                sink.start(journal.run_id, len(protocol.planned_trial_ids), len(journal.completed))
            _emit_metadata(sinks, prepared, session)
            runner = TrialRunner(
                protocol=protocol,
                config=config,
                session=session,
                sinks=sinks,
                journal=journal,
                estimator=prepared.estimator,
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
            log_error = _end_sinks(sinks, session if outcome is not None else None, rig.truth)
    if log_error is not None and outcome.exit_code == ExitCode.OK:  # the rig is safe; the log is not whole
        reason = f"LogWriteError: {log_error}"
        verified = outcome.safe_state_verified
        outcome = RunOutcome(ExitCode.FAULT, "faulted", reason, outcome.new_results, verified)
    with interrupts_held():
        return _finish(prepared, rig.truth, outcome, schedule)


def _end_sinks(
    sinks: tuple[RunSink, ...], session: RigSession | None, truth: GroundTruth | None
) -> LogWriteError | None:
    """The sinks' closing notes, the simulator's truth (every trial's hidden draws), then stop them all.

    A log that cannot be written does not hide how the run ended: the error is returned, not raised,
    and every sink is still stopped.
    """
    error: LogWriteError | None = None
    try:
        now = session.clock.time_ns() if session is not None else time.time_ns()
        notes = [note for sink in sinks if (note := sink.closing_note(now)) is not None]
        for note in notes:
            for sink in sinks:
                sink.log(schemas.LOG, note.time_ns, note.to_payload())
        if sinks and session is not None and truth is not None:
            truth_json = json.dumps(truth.snapshot().to_json(), allow_nan=False)
            for sink in sinks:
                sink.metadata("sim_truth", {"json": truth_json})
    except LogWriteError as exc:
        error = exc
    for sink in sinks:
        try:
            sink.stop()
        except LogWriteError as exc:
            error = error or exc
    return error


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


def _emit_metadata(sinks: tuple[RunSink, ...], prepared: PreparedRun, session: RigSession) -> None:
    """The run's metadata records and attached files, to every sink."""
    request = prepared.request
    session_metadata = {
        "software": f"rig {rig.__version__}",
        "python": platform.python_version(),
        "host": socket.gethostname(),
        "seed": str(prepared.journal.seed),
        "clock": "realtime" if request.realtime or session.kind == RigKind.HARDWARE else "virtual",
        "run_id": prepared.run_id,
        "invocation": str(prepared.journal.invocations),
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    records = [
        ("session", session_metadata),
        ("protocol", prepared.protocol.as_metadata()),
        ("rig", prepared.config.as_metadata()),
    ]
    attachments = [
        (prepared.protocol.source.name, "application/yaml", prepared.protocol.text.encode()),
        (prepared.config.source.name, "application/yaml", prepared.config.text.encode()),
        *session.attachments,
    ]
    for sink in sinks:
        for name, data in records:
            sink.metadata(name, data)
        for name, media_type, body in attachments:
            sink.attachment(name, media_type, body)


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
    """Make the (checked) `--out` directory of a new run.

    Made by another process since the check as something else, it fails here (`mkdir` refuses a
    non-directory) or when the lock file cannot be written there.
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out {out_dir}: cannot create the directory ({exc.strerror or exc})") from None


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
