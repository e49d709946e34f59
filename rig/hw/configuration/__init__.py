"""Configuration sources a rig config can choose (`configuration.source:`), and the factory for them."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = ("factory",)

# The names users import (`from rig.hw.configuration import hardware_configuration_source`), each
# with the module that defines it, loaded on first use (rig.exports).
NAMES = {
    "hardware_configuration_source": "factory",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
