"""Plain test helpers (no fixtures): register value conversions and a scripted world shaft.

Import as `from tests.helpers import ...`; fixtures live in tests/conftest.py.
"""

from __future__ import annotations

import fcntl
import functools
import subprocess
import tempfile
from pathlib import Path

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


# Three joint-estimation slips on joint 1, quick to run: the runner tests' protocol.
QUICK_PROTOCOL = """\
format: rig-protocol/1
name: quick
detector: {arm_threshold_n: 2.0, drop_fraction: 0.15}
ramp: {fast_speed_rad_s: 1.0, slow_speed_rad_s: 0.3, max_force_n: 70.0}
limits: {force_ceiling_n: 75.0}
blocks:
  - kind: joint_estimation
    joint: 1
    distances_m: [0.12, 0.2, 0.25]
    repeats: 1
    steps: [prompt, {tare: {settle_s: 0.1}}, ramp_until_slip, unload]
"""


def write_joint_1_protocol(path: Path, name: str, ramp: str, distances_m: str) -> Path:
    """A one-block joint-estimation protocol on joint 1 (prompt, tare, ramp until slip, unload) at `path`.

    `ramp` is the protocol's ramp mapping in YAML flow style, `distances_m` the block's list of distances.
    """
    path.write_text(
        f"format: rig-protocol/1\nname: {name}\ndetector: {{arm_threshold_n: 2.0, drop_fraction: 0.15}}\n"
        f"ramp: {ramp}\nlimits: {{force_ceiling_n: 75.0}}\nblocks:\n"
        f"  - {{kind: joint_estimation, joint: 1, distances_m: {distances_m}, repeats: 1,\n"
        "     steps: [prompt, {tare: {settle_s: 0.3}}, ramp_until_slip, unload]}\n"
    )
    return path


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
