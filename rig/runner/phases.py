"""The runner's explicit state machine: phases of a run and of a trial, and the allowed transitions."""

from __future__ import annotations

from rig.records import TrialPhase

TERMINAL = frozenset({TrialPhase.DONE, TrialPhase.ABORTED, TrialPhase.FAULTED})
_ANY_ACTIVE = frozenset(TrialPhase) - TERMINAL

# Every active phase may end in ABORTED or FAULTED; these are the forward transitions.
_ALLOWED: dict[TrialPhase, frozenset[TrialPhase]] = {
    TrialPhase.IDLE: frozenset(_ANY_ACTIVE),
    TrialPhase.CONNECTING: frozenset({TrialPhase.IDLE}),
    TrialPhase.TARING: frozenset(_ANY_ACTIVE),
    TrialPhase.BENDING: frozenset(_ANY_ACTIVE),
    TrialPhase.PROMPTING: frozenset(_ANY_ACTIVE),
    TrialPhase.RAMP_FAST: frozenset({TrialPhase.RAMP_SLOW, TrialPhase.UNLOADING}),
    TrialPhase.RAMP_SLOW: frozenset({TrialPhase.UNLOADING}),
    TrialPhase.UNLOADING: frozenset(_ANY_ACTIVE - {TrialPhase.RAMP_FAST, TrialPhase.RAMP_SLOW}),
    TrialPhase.RESETTING: frozenset(_ANY_ACTIVE - {TrialPhase.RAMP_FAST, TrialPhase.RAMP_SLOW}),
    TrialPhase.PAUSING: frozenset(_ANY_ACTIVE),
}


class PhaseMachine:
    """Holds the current phase and refuses transitions that would skip a safety step."""

    def __init__(self) -> None:
        self.phase = TrialPhase.IDLE

    def to(self, new: TrialPhase) -> bool:
        """Move to `new`; returns False (no change) when already there."""
        if new == self.phase:
            return False
        if self.phase in TERMINAL:
            raise RuntimeError(f"run already ended in {self.phase}; cannot go to {new}")
        if (
            new not in (TrialPhase.ABORTED, TrialPhase.FAULTED, TrialPhase.DONE)
            and new not in _ALLOWED[self.phase]
        ):
            raise RuntimeError(f"illegal phase transition {self.phase} -> {new}")
        self.phase = new
        return True
