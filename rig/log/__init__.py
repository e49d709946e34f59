"""MCAP logging, by job: the format (topic schemas), writing, the live view and reading."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "format",
    "live",
    "reading",
    "writing",
)

# The names users import (`from rig.log import LivePublisher`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "LivePublisher": "live.publisher",
    "read_run": "reading.reader",
    "RunLog": "reading.reader",
    "RunLogger": "writing.writer",
    "TOPICS": "format.schemas",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
