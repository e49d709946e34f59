"""Test doubles of the hardware seams (`rig.testing.fakes`): for tests only, never imported by the rig.

An import-linter contract in pyproject.toml ("test doubles are not used at runtime") keeps every
other rig module from importing this package.
"""
