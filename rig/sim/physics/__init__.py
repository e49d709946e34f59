"""The simulated world: the test article, its joints and slips, the winch line and the bending fixture."""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "configuration_source",
    "link_presets",
    "world",
)

# The names users import (`from rig.sim.physics import SimPreset`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "make_preset": "link_presets",
    "SimPreset": "link_presets",
    "SimWorld": "world",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
