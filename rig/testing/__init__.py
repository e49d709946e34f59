"""Wrappers of the hardware seams and camera images for tests: for tests only, never imported by the rig.

The seams' wrappers (`recording`, `injected_errors`, `prompts`) wrap the object-level simulated devices
(`rig.sim.object_devices`, the same world as the byte-level rig): one simulator, no second world.

An import-linter contract in pyproject.toml ("test doubles are not used at runtime") keeps every
other rig module from importing this package.
"""

from rig.exports import lazy_names

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
    "camera_images",
    "camera_scenes",
    "injected_errors",
    "prompts",
    "recording",
)

# The names users import (`from rig.testing import ErrorInjector`), each with the module that
# defines it, loaded on first use (rig.exports).
NAMES = {
    "ErrorInjector": "injected_errors",
    "random_scene": "camera_scenes",
    "RecordingOperator": "prompts",
    "RecordingServoBus": "recording",
    "SyntheticCamera": "camera_images",
}
__all__ = sorted(NAMES)
__getattr__ = lazy_names(__name__, NAMES)
