"""The emulated load cell: signal and line formats, and its in-process and pty transports."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "artefacts",
    "emulator",
    "inprocess_line",
    "line_pty_server",
    "profiles",
)

# The names users import (`from rig.sim.loadcell import LoadCellEmulator`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "LoadCellEmulator": "emulator",
    "serve_loadcell": "line_pty_server",
    "SignalModel": "emulator",
    "simulated_load_cell": "inprocess_line",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
