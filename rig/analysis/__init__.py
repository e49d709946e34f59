"""Analysis of logged runs from Python (docs/analysis.md) and `rig replay`.

`open_log(*paths)` reads one run into a `LoggedRun` (its tables as pandas DataFrames, refits,
re-detection, the report); `open_logs(paths)` several, as `LoggedRuns`.
"""

from rig.analysis.logged_run import LoggedRun, LoggedRuns, LogWarning, Refit, open_log, open_logs

# The modules other packages may import (the others are private to this package: import-linter
# contract "private modules stay private", pyproject.toml), then the library's names.
__all__ = [
    "LogWarning",
    "LoggedRun",
    "LoggedRuns",
    "Refit",
    "logged_run",
    "open_log",
    "open_logs",
    "redetect",
    "replay_run",
    "replay_tables",
    "report",
]
