"""Plain test helpers (no fixtures): register value conversions, a scripted world shaft, test protocols
built in code from the shipped ones, the firmware build and a trial's set-up in the world.

Import as `from tests.helpers import ...`; fixtures live in tests/conftest.py.
"""

from __future__ import annotations

import copy
import fcntl
import functools
import subprocess
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from rig.hw.dxl.control_table import to_signed
from rig.sim.physics.world import SimWorld
from rig.sim.truth import TrialTruth
from rig.vocabulary import TrialKind


def u32(value: int) -> int:
    """A signed register value as the unsigned 32-bit word the SDK sends."""
    return value & 0xFFFFFFFF


def s32(raw: int) -> int:
    """An unsigned 32-bit register word as a signed value."""
    return to_signed(raw, 4)


def s16(raw: int) -> int:
    """An unsigned 16-bit register word as a signed value."""
    return to_signed(raw, 2)


class ScriptedShaft:
    """A servo double for `SimWorld`: the test sets its angle; it records the torque the world applies."""

    def __init__(self, position_rad: float = 0.0) -> None:
        self.present_position_rad = position_rad
        self.external_torque_nm = 0.0


PROTOCOLS_DIR = Path(__file__).resolve().parent.parent / "protocols"


def with_overrides(data: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of `data` with `overrides` applied key by key: a mapping is merged into the mapping
    it overrides (recursively), None deletes the key, anything else (a list, a number) replaces it."""
    merged = copy.deepcopy(dict(data))
    for key, value in overrides.items():
        if value is None:
            merged.pop(key, None)
        elif isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = with_overrides(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def shipped_protocol(stem: str, /, **overrides: Any) -> dict[str, Any]:
    """protocols/STEM.yaml as data, with `overrides` applied (`with_overrides`)."""
    data = yaml.safe_load((PROTOCOLS_DIR / f"{stem}.yaml").read_text(encoding="utf-8"))
    return with_overrides(data, overrides)


def shipped_block(stem: str, index: int = 0, /, **overrides: Any) -> dict[str, Any]:
    """Block `index` of protocols/STEM.yaml, with `overrides` applied (`with_overrides`)."""
    return with_overrides(shipped_protocol(stem)["blocks"][index], overrides)


class _NoAliasDumper(yaml.SafeDumper):
    """A SafeDumper that writes an object used twice twice: protocols refuse YAML aliases."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def protocol_text(data: Mapping[str, Any]) -> str:
    """`data` as protocol YAML, keys in their order, lists and mappings of plain values inline."""
    return yaml.dump(
        dict(data), Dumper=_NoAliasDumper, sort_keys=False, default_flow_style=None, allow_unicode=True
    )


def _one_block_text(
    data: Mapping[str, Any], block: Mapping[str, Any] | None, overrides: Mapping[str, Any]
) -> str:
    """The text of one-block protocol `data` with `overrides` applied, and `block` to its block."""
    varied = with_overrides(data, overrides)
    if block is not None:
        varied["blocks"] = [with_overrides(varied["blocks"][0], block)]
    return protocol_text(varied)


def smoke_protocol(*, block: Mapping[str, Any] | None = None, **overrides: Any) -> str:
    """protocols/smoke.yaml's text with `overrides` applied (`with_overrides`), `block` to its one block."""
    return _one_block_text(shipped_protocol("smoke"), block, overrides)


def write_joint_1_protocol(
    path: Path, name: str, ramp: Mapping[str, float], distances_m: Sequence[float], **block: Any
) -> Path:
    """The shipped smoke protocol named `name`, its ramp with `ramp`, its one block (joint 1) at
    `distances_m` with `block` (`with_overrides`), written to `path`."""
    text = smoke_protocol(
        name=name, description=None, ramp=ramp, block={"distances_m": list(distances_m), **block}
    )
    path.write_text(text, encoding="utf-8")
    return path


def bare_protocol(name: str | None, blocks: Sequence[Mapping[str, Any]], **fields: Any) -> str:
    """A protocol of `blocks` and `fields` alone, every other field at its default, in the shipped
    protocols' format; `name` None leaves the name out (the file's stem names the protocol)."""
    named = {} if name is None else {"name": name}
    data = {"format": shipped_protocol("smoke")["format"], **named, **fields, "blocks": list(blocks)}
    return protocol_text(data)


def adaptive_block(**fields: Any) -> dict[str, Any]:
    """The shipped adaptive block cut to its kind, joint, design and distance range (every other
    field at its default), with `fields` (`with_overrides`)."""
    shipped = shipped_block("joint_estimation_adaptive")
    kept = {key: shipped[key] for key in ("kind", "joint", "design", "distance_range_m")}
    return with_overrides(kept, fields)


# A tare, the ramp until the slip and the unload, after the operator's prompt: the runner tests' steps.
QUICK_STEPS = ["prompt", {"tare": {"settle_s": 0.1}}, "ramp_until_slip", "unload"]
# Three joint-estimation slips on joint 1, quick to run: the runner tests' protocol, the shipped
# smoke protocol at three distances with a faster slow ramp.
QUICK_BLOCK = shipped_block("smoke", distances_m=[0.12, 0.2, 0.25], steps=QUICK_STEPS)
QUICK_PROTOCOL_DATA = shipped_protocol(
    "smoke", name="quick", description=None, ramp={"slow_speed_rad_s": 0.3}, blocks=[QUICK_BLOCK]
)
QUICK_PROTOCOL = protocol_text(QUICK_PROTOCOL_DATA)


def quick_protocol(*, block: Mapping[str, Any] | None = None, **overrides: Any) -> str:
    """QUICK_PROTOCOL's text with `overrides` applied (`with_overrides`), and `block` to its one block."""
    return _one_block_text(QUICK_PROTOCOL_DATA, block, overrides)


# A link-validation trial's steps around QUICK_STEPS' tare, ramp and unload: bend, measure, ..., reset.
QUICK_LINK_STEPS = ["bend", "measure", *QUICK_STEPS[1:], "reset"]


def quick_then_link_validation(name: str, **validation: Any) -> str:
    """QUICK_PROTOCOL's block at 0.12 and 0.2 m, then the shipped link-validation block with `validation`."""
    joint = with_overrides(QUICK_BLOCK, {"distances_m": [0.12, 0.2]})
    return quick_protocol(name=name, blocks=[joint, shipped_block("link_validation", 1, **validation)])


def link_small_protocol(**overrides: Any) -> str:
    """QUICK_PROTOCOL named link_small with the shipped link-validation detector (armed at 1 N): its block
    at 0.1 and 0.2 m, then two configurations of link 1 (QUICK_LINK_STEPS); with `overrides` applied."""
    joint = with_overrides(QUICK_BLOCK, {"distances_m": [0.1, 0.2]})
    validation = shipped_block(
        "link_validation", 1, configurations_deg=[[5] * 8, [10, -10] * 4], steps=QUICK_LINK_STEPS
    )
    link_small = {
        "name": "link_small",
        "detector": shipped_protocol("link_validation")["detector"],
        "blocks": [joint, validation],
    }
    return protocol_text(with_overrides(with_overrides(QUICK_PROTOCOL_DATA, link_small), overrides))


FIRMWARE = Path(__file__).resolve().parent.parent / "firmware"
_FIRMWARE_LOCK = Path(tempfile.gettempdir()) / "rig-firmware-build.lock"


@functools.cache
def build_firmware() -> subprocess.CompletedProcess[str]:
    """`make -C firmware all sim`, once per test process and never two at a time.

    pytest-xdist runs two workers: two fixtures building at once raced on `build/core.a` (a fresh
    clone failed 2 of 4 runs). The build holds an exclusive lock on a file in the temporary
    directory, so the second waits and then finds the image made (make does nothing).
    """
    with open(_FIRMWARE_LOCK, "w", encoding="utf-8") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            return subprocess.run(
                ["make", "-C", str(FIRMWARE), "all", "sim"], capture_output=True, text=True, timeout=600
            )
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def set_up_trial(
    world: SimWorld, kind: TrialKind | str, distance_m: float | None = None, joint: int | None = None
) -> TrialTruth:
    """What a trial does to the world before its ramp, drawn at once (as the loading would draw it).

    Joint estimation: the person hangs the hook at `distance_m` on the specimen (`joint` of the link,
    or the nominal one); link validation: the line goes to the link.
    """
    if TrialKind(kind) is TrialKind.JOINT_ESTIMATION:
        assert distance_m is not None
        world.place_hook(distance_m, joint)
    else:
        world.hook_link()
    return world.draw_trial()
