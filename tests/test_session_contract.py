"""The session contract holds only what a hardware rig has: the hardware builder sets every field.

A field that only a simulation fills (a trial hook, the hidden truth, a log cap, a simulated hand)
would stay at its default on a hardware rig, so it fails this test; such things go beside the
session (`rig.runner.rig_to_run`), not into it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from rig.hw.hardware_rig import hardware_session
from rig.hw.session import RigSession
from rig.inputs.rig_config import load_rig_config
from rig.sim.simulated_rig import simulated_rig

MAX_FIELDS = 12


def _default(field: dataclasses.Field[Any]) -> Any:
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return field.default


def test_the_session_has_at_most_twelve_fields() -> None:
    assert len(dataclasses.fields(RigSession)) <= MAX_FIELDS


def test_the_hardware_builder_sets_every_field_of_the_session(hardware_rig: Any, tmp_path: Path) -> None:
    session = hardware_session(load_rig_config(hardware_rig(tmp_path / "servos", tmp_path / "cell")))
    for field in dataclasses.fields(RigSession):
        value = getattr(session, field.name)
        if field.default is not dataclasses.MISSING or field.default_factory is not dataclasses.MISSING:
            assert value != _default(field), f"a hardware rig leaves RigSession.{field.name} at its default"


def test_the_simulated_rig_keeps_its_truth_beside_the_session() -> None:
    rig = simulated_rig(load_rig_config(None))
    assert isinstance(rig.session, RigSession)
    assert not any(hasattr(rig.session, name) for name in ("truth", "begin_trial", "log_limit_bytes"))
    assert rig.truth.snapshot().world.seed == 0
