"""What a run is given: the rig's session and, beside it, what only the composition knows of that rig.

A hardware rig is its session alone (`BareRig`). A simulated rig also knows its hidden truth (the
capacities the estimates should find; it goes into the log's `sim_truth` metadata and the report)
and may carry a logger fault (the most the run's log file may hold). The runner reads both from
here, never from the session (rig.hw.session), which holds only what a hardware rig has.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

from rig.hw.session import RigSession


class TruthSnapshot(Protocol):
    """The truth at one moment, as the log and the report carry it."""

    def to_json(self, *, with_trials: bool = True) -> dict[str, Any]:
        """JSON-serialisable copy (`with_trials=False`: the summary `rig run --json` prints)."""
        ...


class GroundTruth(Protocol):
    """What a simulated rig knows and a real one cannot: the hidden truth the estimates should find."""

    def snapshot(self) -> TruthSnapshot:
        """The truth now: the world's (every trial's hidden draws and slips) and the rig's state."""
        ...


class RigToRun(Protocol):
    """A rig opened for a run."""

    @property
    def session(self) -> RigSession:
        """What the runner drives."""
        ...

    @property
    def truth(self) -> GroundTruth | None:
        """The hidden truth beside the session (None for a hardware rig)."""
        ...

    @property
    def log_limit_bytes(self) -> int | None:
        """The most the run's log file may hold, writes beyond it failing (None: no limit)."""
        ...


@dataclass(frozen=True)
class BareRig:
    """A rig that is its session alone: a hardware rig, or a test's own session."""

    session: RigSession
    truth: GroundTruth | None = None
    log_limit_bytes: int | None = None
