"""The log format: its version, the topic schemas, the 3D scene payloads and one example per topic."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "encoding",
    "examples",
    "link_scene",
    "log_format",
    "schemas",
    "viewer_schema",
)

# The names users import (`from rig.log.format import LOG_FORMAT_VERSION`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "example_payloads": "examples",
    "LOG_FORMAT_VERSION": "log_format",
    "TOPICS": "schemas",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
