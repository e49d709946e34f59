"""The run journal: a small JSON file, replaced atomically after every trial, that makes `--resume` exact.

It records which protocol and rig config the run uses (with content hashes, so a resume against
edited files is refused), the seed, the planned trial order, every completed trial's result, the
MCAP files written so far, and the run status. Estimates are not stored: on resume they are
rebuilt by replaying the completed results through the same online estimators, which is exact.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from rig.errors import InputError
from rig.files import atomic_write_text
from rig.log.records import TrialResult

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
        }
        atomic_write_text(self.path, json.dumps(payload, indent=1, allow_nan=False) + "\n")

    @classmethod
    def load(cls, path: Path) -> RunJournal:
        """Read a journal; a missing or damaged one is an InputError naming the file."""
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InputError(f"{path}: no journal for this run id in this --out directory") from None
        except (OSError, json.JSONDecodeError) as exc:
            raise InputError(f"{path}: unreadable run journal ({exc})") from None
        if not isinstance(data, dict) or data.get("format") != JOURNAL_FORMAT:
            raise InputError(f"{path}: format: not a {JOURNAL_FORMAT} journal")
        try:
            return cls(
                path=path,
                run_id=str(data["run_id"]),
                protocol_path=str(data["protocol_path"]),
                protocol_hash=str(data["protocol_hash"]),
                rig_path=str(data["rig_path"]),
                rig_hash=str(data["rig_hash"]),
                seed=int(data["seed"]),
                planned_trials=[int(t) for t in data["planned_trials"]],
                completed=[TrialResult.from_json(r) for r in data["completed"]],
                logs=[str(x) for x in data["logs"]],
                status=str(data["status"]),
                invocations=int(data.get("invocations", 0)),
                retried_trials=[int(t) for t in data.get("retried_trials", [])],
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: damaged run journal (field {exc})") from None
