"""The run journal: a small JSON file, replaced atomically after every trial, that makes `--resume` exact.

It records which protocol and rig config the run uses (with content hashes, so a resume against
edited files is refused), the seed, the planned trial order, every completed trial's result, the
MCAP files written so far, and the run status. Estimates are not stored: on resume they are
rebuilt by replaying the completed results through the same online estimators, which is exact.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, assert_never

from rig.errors import InputError
from rig.inputs.files import MAX_YAML_BYTES, atomic_write_text, load_json_file
from rig.inputs.protocol import MAX_TRIALS
from rig.records import TrialKind, TrialResult

JOURNAL_FORMAT = "rig-journal/1"
RUN_STATUSES = ("running", "completed", "aborted", "faulted", "interrupted")


def content_hash(text: str) -> str:
    """SHA-256 of a file's text, to detect a protocol or config edited between run and resume."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass
class RunJournal:
    """The state of one run across invocations (`rig run` and each `--resume`)."""

    path: Path
    run_id: str
    protocol_path: str
    protocol_hash: str
    rig_path: str
    rig_hash: str
    seed: int
    planned_trials: list[int]
    completed: list[TrialResult] = field(default_factory=list)
    logs: list[str] = field(default_factory=list)
    status: str = "running"
    invocations: int = 0
    retried_trials: list[int] = field(default_factory=list)  # one entry per repeat after a device fault
    # Appended (lab-safety issue, finding 6); journals written before them load without them.
    rig_builtin: bool = False  # the run is on the built-in simulated rig (rig_path is where it was then)
    protocol_text: str | None = None  # the files' texts at the start: a resume names what changed
    rig_text: str | None = None

    @staticmethod
    def path_for(out_dir: Path, run_id: str) -> Path:
        """Where the journal of `run_id` lives inside `out_dir`."""
        return out_dir / f"{run_id}.journal.json"

    @property
    def completed_ids(self) -> set[int]:
        """Trial ids already done (whatever their outcome)."""
        return {r.trial_id for r in self.completed}

    def record_trial(self, result: TrialResult) -> None:
        """Append one finished trial and persist atomically."""
        self.completed.append(result)
        self.save()

    def record_retry(self, trial_id: int) -> None:
        """Count one repeat of a trial after a device fault, and persist."""
        self.retried_trials.append(trial_id)
        self.save()

    def save(self) -> None:
        """Replace the journal file atomically (readers see the old or the new one)."""
        payload = {
            "format": JOURNAL_FORMAT,
            "run_id": self.run_id,
            "protocol_path": self.protocol_path,
            "protocol_hash": self.protocol_hash,
            "rig_path": self.rig_path,
            "rig_hash": self.rig_hash,
            "seed": self.seed,
            "planned_trials": self.planned_trials,
            "completed": [r.to_json() for r in self.completed],
            "logs": self.logs,
            "status": self.status,
            "invocations": self.invocations,
            "retried_trials": self.retried_trials,
            "rig_builtin": self.rig_builtin,
            "protocol_text": self.protocol_text,
            "rig_text": self.rig_text,
        }
        atomic_write_text(self.path, json.dumps(payload, indent=1, allow_nan=False) + "\n")

    @classmethod
    def load(cls, path: Path) -> RunJournal:
        """Read a journal; a missing or damaged one is an InputError naming the file (and field)."""
        try:
            missing = not path.exists()
        except OSError:
            missing = True
        if missing:
            raise InputError(f"{path}: no journal for this run id in this --out directory")
        data = load_json_file(path, what="a run journal (JSON)")
        if not isinstance(data, dict) or data.get("format") != JOURNAL_FORMAT:
            raise InputError(f"{path}: format: not a {JOURNAL_FORMAT} journal")

        def fail(field: str, problem: str) -> InputError:
            return InputError(f"{path}: {field}: {problem}; allowed: a journal as `rig run` writes it (§7.1)")

        def text(field: str) -> str:
            value = data.get(field)
            if not isinstance(value, str) or not 0 < len(value) <= 4096:
                raise fail(field, f"expected a non-empty string, got {_short(value)}")
            return value

        def integer(value: Any, field: str, lo: int, hi: int) -> int:
            if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
                raise fail(field, f"expected an integer from {lo} to {hi}, got {_short(value)}")
            return value

        def flag(field: str) -> bool:
            value = data.get(field, False)
            if not isinstance(value, bool):
                raise fail(field, f"expected true or false, got {_short(value)}")
            return value

        def optional_text(field: str) -> str | None:
            value = data.get(field)
            if value is not None and (not isinstance(value, str) or len(value) > MAX_YAML_BYTES):
                raise fail(field, f"expected null or a file's text of at most {MAX_YAML_BYTES} characters")
            return value

        def items(field: str) -> list[Any]:
            value = data.get(field)
            if not isinstance(value, list) or len(value) > MAX_TRIALS:
                raise fail(field, f"expected a list of at most {MAX_TRIALS} items, got {_short(value)}")
            return value

        planned = [
            integer(t, f"planned_trials[{i}]", 1, MAX_TRIALS) for i, t in enumerate(items("planned_trials"))
        ]
        if len(set(planned)) != len(planned):
            raise fail("planned_trials", "a trial id appears twice")
        completed = [_trial(r, f"completed[{i}]", fail) for i, r in enumerate(items("completed"))]
        ids = [r.trial_id for r in completed]
        if len(set(ids)) != len(ids) or not set(ids) <= set(planned):
            raise fail("completed", "trial ids repeated or not in planned_trials")
        logs = items("logs")
        for i, log in enumerate(logs):
            if not isinstance(log, str):
                raise fail(f"logs[{i}]", f"expected a path, got {_short(log)}")
        status = data.get("status")
        if status not in RUN_STATUSES:
            raise fail("status", f"{_short(status)}; allowed: {', '.join(RUN_STATUSES)}")
        return cls(
            path=path,
            run_id=text("run_id"),
            protocol_path=text("protocol_path"),
            protocol_hash=text("protocol_hash"),
            rig_path=text("rig_path"),
            rig_hash=text("rig_hash"),
            seed=integer(data.get("seed"), "seed", 0, MAX_SEED),
            planned_trials=planned,
            completed=completed,
            logs=list(logs),
            status=str(status),
            invocations=integer(data.get("invocations", 0), "invocations", 0, 1_000_000),
            retried_trials=[
                integer(t, f"retried_trials[{i}]", 1, MAX_TRIALS)
                for i, t in enumerate(items("retried_trials") if "retried_trials" in data else [])
            ],
            rig_builtin=flag("rig_builtin"),
            protocol_text=optional_text("protocol_text"),
            rig_text=optional_text("rig_text"),
        )


# The ranges of a journalled slip that the estimators can replay (docs/formats.md §7.2).
MAX_SEED = 2**64 - 1
_DISTANCE_RANGE_M = (0.001, 2.0)  # the protocol's
_MASS_RANGE_KG = (1e-6, 1e4)
_FORCE_RANGE_N = (1e-6, 1e5)
_LEVER_RANGE_M = (0.0, 100.0)


def _trial(raw: Any, field: str, fail: Callable[[str, str], InputError]) -> TrialResult:
    """One journalled trial record, checked so that replaying it through the estimators cannot fail."""
    if not isinstance(raw, dict):
        raise fail(field, f"expected a trial record (an object), got {_short(raw)}")
    try:
        result = TrialResult.from_json(raw)
    except KeyError as exc:
        raise fail(field, f"field {exc} is missing") from None
    except (TypeError, ValueError, OverflowError) as exc:
        raise fail(field, _short_text(str(exc), 120)) from None
    if not result.slipped:
        return result

    def check(name: str, value: float | None, bounds: tuple[float, float]) -> None:
        if value is None or not bounds[0] <= value <= bounds[1]:
            raise fail(f"{field}.{name}", f"{value!r} for a slip; allowed: {bounds[0]:g} to {bounds[1]:g}")

    match result.kind:
        case TrialKind.JOINT_ESTIMATION:
            check("distance_m", result.distance_m, _DISTANCE_RANGE_M)
            check("slip_mass_kg", result.slip_mass_kg, _MASS_RANGE_KG)
        case TrialKind.LINK_VALIDATION:
            check("peak_force_n", result.peak_force_n, _FORCE_RANGE_N)
            arms = result.lever_arms_m
            if not arms or len(arms) > 100:
                raise fail(
                    f"{field}.lever_arms_m", f"{_short(arms)} for a slip; allowed: 1-100 lever arms [m]"
                )
            for j, arm in enumerate(arms):
                check(f"lever_arms_m[{j}]", arm, _LEVER_RANGE_M)
        case kind:
            assert_never(kind)
    return result


def _short(value: Any) -> str:
    if isinstance(value, int) and value.bit_length() > 100:
        return "an integer beyond the float range"
    return _short_text(repr(value))


def _short_text(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."
