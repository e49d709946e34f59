"""The live view: the run's topics served over the Foxglove WebSocket protocol."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = ("publisher",)

# The names users import (`from rig.log.live import LivePublisher`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "LivePublisher": "publisher",
    "serve_log": "publisher",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
