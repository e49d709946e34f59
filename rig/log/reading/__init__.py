"""Reading logs: bounded MCAP scanning, the tolerant run reader and payloads as columns."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = ("reader",)

# The names users import (`from rig.log.reading import RunLog`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "mcap_files": "reader",
    "read_run": "reader",
    "RunLog": "reader",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
