"""The slip-trial rig: hardware, simulation, protocol runner, MCAP logging and the `rig` CLI."""

from rig.exports import lazy_names

__version__ = "0.1.0"

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "errors",
    "inputs",
    "records",
    "rigs",
    "safety",
    "vocabulary",
)

# The names users import (`from rig import ExitCode`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "ExitCode": "errors",
    "InputError": "errors",
    "open_rig": "rigs",
    "open_simulated_rig": "rigs",
    "RigError": "errors",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
