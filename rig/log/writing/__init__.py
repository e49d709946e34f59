"""Writing a run's MCAP log: the batched logger and its writer process."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = ("writer",)

# The names users import (`from rig.log.writing import LogWriteError`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "LogWriteError": "writer",
    "RunLogger": "writer",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
