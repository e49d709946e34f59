"""The slip-trial rig: hardware, simulation, protocol runner, MCAP logging and the `rig` CLI."""

__version__ = "0.1.0"

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "errors",
    "inputs",
    "records",
    "rigs",
    "safety",
    "vocabulary",
]
