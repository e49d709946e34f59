"""Fork bending: the chain statics decide which joint turns and by how much; corrections converge."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from rig.hw.bending import ForkBending
from rig.sim.physics.forks import ForkFixture
from rig.sim.physics.link import ChainLink
from rig.sim.physics.link_presets import make_preset
from rig.sim.physics.world import SimWorld
from tests.helpers import ScriptedShaft, set_up_trial

MS = 1_000_000


def link(capacities: list[float]) -> ChainLink:
    return ChainLink([0.03] * len(capacities), (0.0, 0.0, 0.03), (0.0, -1.0, 0.0), capacities)


def push(fixture: ForkFixture, component: int, travel_rad: float, steps: int = 40) -> None:
    fixture.engage(component, 0.0)
    for angle in np.linspace(0.0, travel_rad, steps):
        fixture.update(float(angle))
    fixture.active = None


def forks(article: ChainLink, components: list[int]) -> ForkFixture:
    return ForkFixture(
        article, components, pinion_radius_m=0.01, contact_stiffness_n_per_m=1e5, kinetic_ratio=0.8
    )


def test_the_joint_whose_moment_exceeds_its_capacity_most_turns_and_capacities_decide_which() -> None:
    # A fork on component 4 with another on 2: the load reaches joints 3 and 4 only. Joint 3's lever
    # arm (to the contact at o_5) is twice joint 4's, so with equal capacities joint 3 turns...
    equal = link([1.5] * 8)
    fixture = forks(equal, [2, 4])
    assert list(fixture.segment(4)) == [3, 4]
    push(fixture, 4, 0.5)
    angles = np.array(equal.planar_joint_angles())
    assert angles[2] > 0.05 and np.count_nonzero(angles) == 1
    # ... and with joint 3 three times stronger, joint 4 turns instead.
    strong3 = link([1.5, 1.5, 4.5, 1.5, 1.5, 1.5, 1.5, 1.5])
    push(forks(strong3, [2, 4]), 4, 0.5)
    angles = np.array(strong3.planar_joint_angles())
    assert angles[3] > 0.05 and np.count_nonzero(angles) == 1


def test_a_stronger_joint_falls_further_short_of_the_fork_travel() -> None:
    shortfalls = []
    for capacity in (1.0, 2.0):
        article = link([capacity] * 8)
        push(forks(article, list(range(1, 9))), 1, 0.5)
        reached = article.planar_joint_angles()[0]
        free = math.asin(0.01 * 0.5 / 0.03)  # the angle if the contact followed the fork exactly
        shortfalls.append(free - reached)
    assert 0 < shortfalls[0] < shortfalls[1]
    # Between κ·N/(k·L²) and N/(k·L²) (stick-slip under a compliant contact).
    for capacity, shortfall in zip((1.0, 2.0), shortfalls, strict=True):
        scale = capacity / (1e5 * 0.03**2)
        assert 0.75 * scale < shortfall < 1.05 * scale


def test_bend_then_correct_reaches_the_target_within_a_fraction_of_a_degree() -> None:
    capacities = list(1.583 * (1 + 0.1 * np.random.default_rng(0).standard_normal(8)))
    article = link(capacities)
    fixture = forks(article, list(range(1, 9)))
    bending = ForkBending({i + 10: i for i in range(1, 9)}, [0.03] * 8, (0.0, 0.0, 0.03), 0.01)
    target = np.radians([-11.1, 9.5, 7.1, 15.7, -16.5, -3.1, -18.8, -11.3])
    shafts = {i + 10: 0.0 for i in range(1, 9)}
    worst = []
    present = np.zeros(8)
    for attempt in range(2):
        stages = bending.bend_stages(target, present, shafts, correcting=attempt > 0)
        assert [s.component for s in stages] == sorted(s.component for s in stages)  # base to tip
        for stage in stages:
            fixture.engage(stage.component, shafts[stage.servo_id])
            for angle in np.linspace(shafts[stage.servo_id], stage.goal_rad, 30):
                fixture.update(float(angle))
            shafts[stage.servo_id] = stage.goal_rad
            fixture.active = None
        present = np.array(article.planar_joint_angles())
        worst.append(np.degrees(np.abs(present - target).max()))
    assert 0.5 < worst[0] < 2.0  # the first bend falls short by the contact's deflection
    assert worst[1] < 0.3  # one correction, with the learned shortfall, gets within 0.3 deg


def test_the_world_holds_the_link_while_a_fork_pushes_and_frees_it_after() -> None:
    preset = make_preset("link1", seed=1)
    winch, fork_shaft = ScriptedShaft(), ScriptedShaft()
    world = SimWorld(preset, winch, forks=[(1, fork_shaft)], seed=1)
    set_up_trial(world, "link_validation")
    world.engage_fork(1)
    assert world.bending
    fork_shaft.present_position_rad = 0.5
    winch.present_position_rad = preset.winch_slack_rad + 50.0  # a taut line cannot make it slip
    world.advance_to(200 * MS)
    assert not world.slips
    angle = world.link.planar_joint_angles()[0]
    assert angle > 0.1
    world.forks.open()
    assert not world.bending
    world.advance_to(201 * MS)
    assert world.slips  # free now: the overloaded link slips


def test_a_reset_straightens_the_link_exactly() -> None:
    world = SimWorld(
        replace(make_preset("link1"), sigma_bend_rad=0.0), ScriptedShaft(), forks=[(1, ScriptedShaft())]
    )
    world.bend_by_hand([0.1] * 8)
    world.straighten()
    assert world.link.planar_joint_angles() == (0.0,) * 8
