"""The input files: protocols, rig configs, link files, and the parsing and validation they share."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "files",
    "linkfile",
    "protocol",
    "rig_config",
    "servo_ratings",
    "validate",
)

# The names users import (`from rig.inputs import LinkSpec`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "LinkSpec": "linkfile",
    "load_link_file": "linkfile",
    "load_protocol": "protocol",
    "load_rig_config": "rig_config",
    "parse_protocol": "protocol",
    "parse_rig_config": "rig_config",
    "Protocol": "protocol",
    "RigConfig": "rig_config",
    "TrialPlan": "protocol",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
