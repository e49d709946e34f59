"""The "not used at runtime" contract on `rig.testing` names every other top-level rig module."""

from __future__ import annotations

import pkgutil
import tomllib
from pathlib import Path

import rig

ROOT = Path(__file__).resolve().parent.parent


def test_every_rig_module_but_the_test_doubles_is_a_source_of_the_contract() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    contracts = config["tool"]["importlinter"]["contracts"]
    (contract,) = [c for c in contracts if c.get("forbidden_modules") == ["rig.testing"]]
    top_level = {f"rig.{m.name}" for m in pkgutil.iter_modules(rig.__path__)} - {"rig.testing"}
    assert set(contract["source_modules"]) == top_level


def test_every_module_of_rig_testing_is_public() -> None:
    """Tests import each of them; `PUBLIC_MODULES` ("private modules stay private") names them all."""
    import rig.testing

    modules = {m.name for m in pkgutil.iter_modules(rig.testing.__path__)}
    assert set(rig.testing.PUBLIC_MODULES) == modules
