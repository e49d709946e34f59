"""The protocol runner: plan, state machine, interlocks, journal, and the trial loop."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "journal",
    "limits",
    "planning",
    "progress",
    "rig_to_run",
    "run",
    "safety",
    "sinks",
    "trial_runner",
]
