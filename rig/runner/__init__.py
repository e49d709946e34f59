"""The protocol runner: plan, state machine, interlocks, journal, and the trial loop."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "control_loop",
    "execute",
    "journal",
    "limits",
    "planning",
    "progress",
    "recorder",
    "rig_to_run",
    "sinks",
    "trial_runner",
)

# The names users import (`from rig.runner import RunReport`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "execute_run": "execute",
    "prepare_run": "execute",
    "RunReport": "execute",
    "RunRequest": "execute",
    "RunSink": "sinks",
    "TrialRunner": "trial_runner",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
