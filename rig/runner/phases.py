"""The runner's explicit state machine: phases of a run and of a trial, and the allowed transitions."""

from __future__ import annotations

from rig.records import TrialPhase

# The phase names are part of the MCAP contract (`/rig/trial/state`), so they live with the schemas.
Phase = TrialPhase

TERMINAL = frozenset({Phase.DONE, Phase.ABORTED, Phase.FAULTED})
_ANY_ACTIVE = frozenset(Phase) - TERMINAL

# Every active phase may end in ABORTED or FAULTED; these are the forward transitions.
_ALLOWED: dict[Phase, frozenset[Phase]] = {
    Phase.IDLE: frozenset(_ANY_ACTIVE),
    Phase.CONNECTING: frozenset({Phase.IDLE}),
    Phase.TARING: frozenset(_ANY_ACTIVE),
    Phase.BENDING: frozenset(_ANY_ACTIVE),
    Phase.PROMPTING: frozenset(_ANY_ACTIVE),
    Phase.RAMP_FAST: frozenset({Phase.RAMP_SLOW, Phase.UNLOADING}),
    Phase.RAMP_SLOW: frozenset({Phase.UNLOADING}),
    Phase.UNLOADING: frozenset(_ANY_ACTIVE - {Phase.RAMP_FAST, Phase.RAMP_SLOW}),
    Phase.RESETTING: frozenset(_ANY_ACTIVE - {Phase.RAMP_FAST, Phase.RAMP_SLOW}),
    Phase.PAUSING: frozenset(_ANY_ACTIVE),
}


class PhaseMachine:
    """Holds the current phase and refuses transitions that would skip a safety step."""

    def __init__(self) -> None:
        self.phase = Phase.IDLE

    def to(self, new: Phase) -> bool:
        """Move to `new`; returns False (no change) when already there."""
        if new == self.phase:
            return False
        if self.phase in TERMINAL:
            raise RuntimeError(f"run already ended in {self.phase}; cannot go to {new}")
        if new not in (Phase.ABORTED, Phase.FAULTED, Phase.DONE) and new not in _ALLOWED[self.phase]:
            raise RuntimeError(f"illegal phase transition {self.phase} -> {new}")
        self.phase = new
        return True
