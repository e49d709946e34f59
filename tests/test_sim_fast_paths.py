"""The simulator's fast paths (batch tension lookup, batch ADC counts) equal the plain paths exactly."""

from __future__ import annotations

import math
import random

import pytest

from rig.hw.seams import LoadCellSample
from rig.sim.kinds import SlipKind
from rig.sim.loadcell.emulator import SignalModel
from rig.sim.object_devices import ObjectLoadCell, ObjectServoBus, gauss_draws
from rig.sim.physics.link_presets import make_preset
from rig.sim.physics.world import SimWorld
from rig.sim.settings import SlipKindMix
from rig.sim.virtual_clock import DEFAULT_EPOCH_NS, VirtualClock
from tests.helpers import set_up_trial


def _ramping_world() -> SimWorld:
    """A world whose winch reels in steps, so its tension history rises, slips and holds."""
    clock = VirtualClock()
    bus = ObjectServoBus(clock, [(1, "XM430-W350")])
    world = SimWorld(make_preset("link1", 0), bus.servo(1), step_devices=bus.advance_to)
    clock.on_advance(world.advance_to)
    set_up_trial(world, "joint_estimation", distance_m=0.1)
    bus.set_torque([1], True)
    winch = bus.servo(1)
    goal = winch.present_position_rad
    for _ in range(150):
        goal += 0.02
        bus.write_goal_positions({1: goal})
        clock.sleep(0.0137)
    return world


def _scripted_world(skip_still: bool, steps: list[int]) -> tuple[SimWorld, ObjectServoBus]:
    """Reel to slips, hold, release, torque off, in uneven clock steps; `skip_still`: the rest fast path.

    `steps` gets the time of every device step.
    """
    clock = VirtualClock()
    bus = ObjectServoBus(clock, [(1, "XM430-W350"), (2, "XM430-W350")])

    def step_devices(t_ns: int) -> None:
        steps.append(t_ns)
        bus.advance_to(t_ns)

    world = SimWorld(
        make_preset("link1", 2),
        bus.servo(1),
        forks=[(1, bus.servo(2))],
        step_devices=step_devices,
        devices_at_rest=bus.at_rest if skip_still else None,
    )
    clock.on_advance(world.advance_to)
    bus.set_torque([1, 2], True)
    for trial in range(4):
        set_up_trial(world, "joint_estimation", distance_m=0.05 + 0.05 * trial)
        goal = bus.servo(1).present_position_rad
        for _ in range(120):  # reel on past the slip
            goal += 0.03
            bus.write_goal_positions({1: goal})
            clock.sleep(0.0213)
        clock.sleep(0.5)  # hold: the winch settles under the load
        clock.sleep(0.0004)
        bus.write_goal_positions({1: goal - 3.0})  # release
        clock.sleep(0.7)
        if trial == 2:
            bus.set_torque([1], False)  # idle shaft
            clock.sleep(0.3)
            bus.set_torque([1], True)
    return world, bus


def test_skipping_still_stretches_changes_nothing() -> None:
    """The world with the devices' at-rest hook integrates exactly as the one without it."""
    plain_steps: list[int] = []
    fast_steps: list[int] = []
    plain, plain_bus = _scripted_world(False, plain_steps)
    fast, fast_bus = _scripted_world(True, fast_steps)
    assert len(plain.slips) >= 4
    assert len(fast_steps) < 0.9 * len(plain_steps)  # the still stretches were skipped
    assert fast.history.times_ns == plain.history.times_ns
    assert fast.history.tensions_n == plain.history.tensions_n
    assert fast.truth() == plain.truth()
    for a, b in zip(plain_bus.servos, fast_bus.servos, strict=True):
        assert (a.state, a._now_ns, a._at_limit_ns, a.hardware_error) == (
            b.state,
            b._now_ns,
            b._at_limit_ns,
            b.hardware_error,
        )


def _slip_kind_world(plain: bool, mix: SlipKindMix, seed: int) -> tuple[SimWorld, ObjectServoBus]:
    """Joint-estimation and bent-link trials of `mix` on object-level servos; `plain`: every substep plain."""
    clock = VirtualClock()
    bus = ObjectServoBus(clock, [(1, "XM430-W350"), (2, "XM430-W350")])
    world = SimWorld(
        make_preset("link1", seed, slip_mix=mix),
        bus.servo(1),
        forks=[(1, bus.servo(2))],
        step_devices=bus.advance_to,
        devices_at_rest=bus.at_rest,
        seed=seed,
    )
    world.plain_substeps = plain
    clock.on_advance(world.advance_to)
    bus.set_torque([1, 2], True)
    for trial in range(6):
        if trial % 3 == 2:
            set_up_trial(world, "link_validation")
            world.engage_fork(1)
            bus.write_goal_positions({2: bus.servo(2).present_position_rad + 1.0})
            clock.sleep(1.5)  # the fork pushes component 1 and holds the link
            world.forks.open()
        else:
            set_up_trial(world, "joint_estimation", distance_m=0.06 + 0.04 * trial, joint=1 + trial % 8)
        goal = bus.servo(1).present_position_rad
        for _ in range(200):  # a slow reel past the slip load (creep and trains take their time)
            goal += 0.012
            bus.write_goal_positions({1: goal})
            clock.sleep(0.0173)
        clock.sleep(0.4)  # hold
        bus.write_goal_positions({1: goal - 4.0})  # release
        clock.sleep(0.6)
    return world, bus


MIXES = {
    kind: SlipKindMix(probabilities=tuple(1.0 if k == kind else 0.0 for k in SlipKind))
    for kind in SlipKind
    if kind != "no_slip"
} | {"mixed": SlipKindMix(probabilities=(0.3, 0.15, 0.15, 0.15, 0.15, 0.1))}


@pytest.mark.slow
@pytest.mark.parametrize("mix", list(MIXES), ids=list(MIXES))
def test_the_inlined_substep_equals_the_plain_substep(mix: str) -> None:
    """`SimWorld.advance_to`'s inlined substep (and still-stretch skip) integrates as `_substep` does."""
    plain, plain_bus = _slip_kind_world(True, MIXES[mix], 5)
    fast, fast_bus = _slip_kind_world(False, MIXES[mix], 5)
    kinds = {s.onset.kind for s in plain.slips}
    assert mix in kinds or (mix == "mixed" and len(kinds) >= 2), kinds  # the kind under test happened
    assert fast.history.times_ns == plain.history.times_ns
    assert fast.history.tensions_n == plain.history.tensions_n
    assert fast.truth() == plain.truth()
    assert fast.link.planar_joint_angles() == plain.link.planar_joint_angles()
    for a, b in zip(plain_bus.servos, fast_bus.servos, strict=True):
        assert (a.state, a._now_ns, a.hardware_error) == (b.state, b._now_ns, b.hardware_error)


def test_batch_tension_lookup_equals_the_per_time_lookup() -> None:
    world = _ramping_world()
    times = world.history.times_ns
    assert max(world.history.tensions_n) > 1.0  # the line was loaded
    rng = random.Random(5)
    first, last = times[0], world.now_ns + 3_000_000
    for _ in range(200):
        batch = sorted(rng.randint(first, last) for _ in range(rng.randint(0, 40)))
        batch += [t for t in times[-3:]]  # exactly on recorded times, and repeated times
        batch.sort()
        assert world.tensions_at(batch) == [world.tension_at(t) for t in batch]
    with pytest.raises(ValueError, match="older than the tension history"):
        world.tensions_at([first - 1, first])


@pytest.mark.parametrize(
    "signal",
    [SignalModel(), SignalModel(noise_counts=4000.0, quantisation_counts=16), SignalModel(adc_bits=16)],
)
def test_batch_counts_equal_the_per_sample_counts(signal: SignalModel) -> None:
    rng = random.Random(3)
    tensions = [rng.uniform(-200.0, 200.0) for _ in range(5000)] + [1e6, -1e6, 0.0]
    elapsed = [rng.uniform(0.0, 1e4) for _ in tensions]
    draws = [rng.gauss(0.0, 1.0) for _ in tensions]
    expected = [signal.counts(t, e, d) for t, e, d in zip(tensions, elapsed, draws, strict=True)]
    assert signal.counts_many(tensions, elapsed, draws) == expected
    assert signal.adc_min in expected and signal.adc_max in expected  # both ends of the clamp


def test_object_load_cell_batch_path_equals_the_per_sample_path() -> None:
    """The cell with the world's batch lookup and the one without give the very same samples."""

    def tension(t_ns: int) -> float:
        return 5.0 + 3.0 * math.sin(t_ns / 7e7)

    def tensions(times_ns: object) -> list[float]:
        return [tension(t) for t in times_ns]  # type: ignore[attr-defined]

    cells = []
    for batch in (None, tensions):
        clock = VirtualClock()
        cell = ObjectLoadCell(tension, clock, rate_hz=1000.0, signal=SignalModel(), seed=4, tensions_n=batch)
        clock.sleep(0.0123)
        cell.open()
        out = []
        for step_s in (0.02, 0.0005, 0.0, 0.031, 0.02):
            clock.sleep(step_s)
            out.extend(cell.poll())
        cell.close()
        clock.sleep(0.05)
        cell.open()
        clock.sleep(0.02)
        out.extend(cell.poll())
        cells.append(out)
    assert len(cells[0]) == 91  # 71 samples, then 20 after the re-open (1 kHz)
    assert cells[0] == cells[1]
    first = cells[1][0]
    assert type(first) is LoadCellSample and first.seq is None and first.device_time_us is None
    assert first.force_n == pytest.approx(tension(first.time_ns - DEFAULT_EPOCH_NS), abs=0.05)


def test_gauss_draws_equal_random_gauss() -> None:
    """The same numbers as `random.gauss(0, 1)` in any batch sizes, the generator left in step."""
    plain, fast = random.Random(9), random.Random(9)
    sizes = [0, 1, 1, 2, 3, 20, 7, 0, 1, 1000, 5, 2]
    for size in sizes:
        expected = [plain.gauss(0.0, 1.0) for _ in range(size)]
        assert gauss_draws(fast, size) == expected
        assert fast.getstate() == plain.getstate() and fast.gauss_next == plain.gauss_next
