"""Analysis of logged runs from Python (docs/analysis.md) and `rig replay`.

`open_log(*paths)` reads one run into a `LoggedRun` (its tables as pandas DataFrames, refits,
re-detection, the report); `open_logs(paths)` several, as `LoggedRuns`.
"""

from rig.analysis.logged_run import LoggedRun, LoggedRuns, LogWarning, Refit, open_log, open_logs

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "logged_run",
    "redetect",
    "replay_run",
    "replay_tables",
    "report",
)

# The names users import (`from rig.analysis import open_log`).
__all__ = [
    "LogWarning",
    "LoggedRun",
    "LoggedRuns",
    "Refit",
    "open_log",
    "open_logs",
]
