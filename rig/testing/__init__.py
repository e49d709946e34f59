"""Test doubles of the hardware seams (`rig.testing.fakes`): for tests only, never imported by the rig.

An import-linter contract in pyproject.toml ("test doubles are not used at runtime") keeps every
other rig module from importing this package.
"""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "camera_images",
    "camera_scenes",
    "fakes",
]
