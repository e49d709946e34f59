"""The simulated bending fixture: forks on named components, whose outcome the chain statics decide.

Each bender servo drives a **fork** on one component c of the link (docs/bending.md): a rack and
pinion turns shaft rotation into travel along the base x axis (horizontal, across the straight
link), `x_fork = x_0 + r·(θ − θ_0)`, from where the fork closed on the component. The fork touches
the component at its distal end (o_{c+1}; the acting point Q for the tip component) through a
compliant contact of stiffness k, so it pushes with `F = k·(x_fork − x_contact)` along x.

A bend runs the forks one at a time, base to tip. While fork c moves, every fork proximal to it
holds its component and the base is clamped, so the load reaches only the joints of its **segment**,
from the nearest held fork's component (exclusive) to c; the forks distal to it are open. The load
propagates by the chain statics: joint i of the segment carries the moment `F·(P − o_i)_z` about y
(the planar form of `(P − o_i) × F`). The joint whose moment exceeds its true capacity by the most
turns first, about y, until its moment has fallen to the kinetic level (κ × capacity) — which takes
some of the fork's deflection — and then the others are checked again in the new geometry, in
order; joints that stay below capacity do not move. So which joint turns, and by how much less
than the fork travelled (the contact's deflection at the slip load, ~κN/(k·lever) — larger for a
stronger joint), depends on the link's hidden capacities, as on a real link.

A reset straightens the link against a straight guide bar (exactly straight) while the forks open.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from model.chain import forward_kinematics
from rig.sim.physics.link import ChainLink

MAX_YIELDS_PER_UPDATE = 64  # slips resolved per update (each moves one joint; a few suffice)


@dataclass
class Fork:
    """One fork: the component it pushes and the shaft that drives it."""

    component: int  # 1-based component (the one distal to joint `component`)
    shaft_angle: float = 0.0  # the shaft's angle when the fork closed on its component
    contact_x_m: float = 0.0  # the contact's x when the fork closed (no deflection then)
    engaged: bool = False


class ForkFixture:
    """Forks on a `ChainLink`; see the module docstring."""

    def __init__(
        self,
        link: ChainLink,
        components: list[int],
        *,
        pinion_radius_m: float,
        contact_stiffness_n_per_m: float,
        kinetic_ratio: float,
    ) -> None:
        if sorted(set(components)) != sorted(components) or not all(
            1 <= c <= link.joint_count for c in components
        ):
            raise ValueError(
                f"fork components {components}; allowed: distinct, each in 1..{link.joint_count}"
            )
        self.link = link
        self.forks = {c: Fork(c) for c in sorted(components)}
        self.pinion_radius_m = float(pinion_radius_m)
        self.stiffness_n_per_m = float(contact_stiffness_n_per_m)
        self.kinetic_ratio = float(kinetic_ratio)
        self.active: int | None = None  # the component whose fork is moving
        self.yields: list[tuple[int, float]] = []  # (joint, rad) of every slip the forks caused

    def segment(self, component: int) -> range:
        """The joints (1-based) that fork `component` loads: after the nearest proximal fork, up to it."""
        held = [c for c in self.forks if c < component]
        return range((max(held) if held else 0) + 1, component + 1)

    def engage(self, component: int, shaft_angle: float) -> None:
        """Close fork `component` on its component (no deflection) and make it the moving one."""
        fork = self.forks[component]
        fork.shaft_angle = float(shaft_angle)
        fork.contact_x_m = float(self._contact_w(component)[0])
        fork.engaged = True
        self.active = component

    def open_all(self) -> None:
        """Open every fork (after a bend, before the trial loads the link; at a reset)."""
        for fork in self.forks.values():
            fork.engaged = False
        self.active = None

    def update(self, shaft_angle: float) -> bool:
        """Let the link follow the active fork at shaft angle `shaft_angle`; True if a joint turned."""
        if self.active is None:
            return False
        fork = self.forks[self.active]
        fork_x = fork.contact_x_m + self.pinion_radius_m * (float(shaft_angle) - fork.shaft_angle)
        joints = self.segment(self.active)
        angles = np.asarray(self.link.planar_joint_angles() or np.zeros(self.link.joint_count), dtype=float)
        capacities = np.asarray(self.link.capacities_nm)
        moved = False
        for _ in range(MAX_YIELDS_PER_UPDATE):
            poses = forward_kinematics(self.link.transforms)
            contact = self._contact_from(poses, self.active)
            deflection = fork_x - float(contact[0])
            force = self.stiffness_n_per_m * deflection
            levers = np.array([contact[2] - poses[j, 2, 3] for j in joints])  # (P − o_j)_z
            caps = capacities[[j - 1 for j in joints]]
            ratios = np.abs(force * levers) / caps
            worst = int(np.argmax(ratios))
            if ratios[worst] <= 1.0 or levers[worst] == 0.0:
                break
            joint, lever = joints[worst], float(levers[worst])
            kept = (
                np.sign(deflection) * self.kinetic_ratio * caps[worst] / (self.stiffness_n_per_m * abs(lever))
            )
            turn = (deflection - kept) / lever
            angles[joint - 1] += turn
            self.link.set_joint_angles(angles)
            self.yields.append((joint, turn))
            moved = True
        return moved

    def _contact_w(self, component: int) -> np.ndarray:
        return self._contact_from(forward_kinematics(self.link.transforms), component)

    def _contact_from(self, poses: np.ndarray, component: int) -> np.ndarray:
        if component < self.link.joint_count:
            return np.asarray(poses[component + 1, :3, 3], dtype=float)
        return np.asarray(self.link.acting_point_w(), dtype=float)


class ForkShaft(Protocol):
    """A bender's output shaft as the forks see it."""

    @property
    def present_position_rad(self) -> float:
        """Output-shaft angle [rad], multi-turn."""
        ...


class ShaftDrivenForks:
    """The fixture's forks driven by their bender shafts, re-posing the link as the active one moves.

    A pushing fork re-poses the link every `update_ns` (each re-pose costs about 0.2 ms), and once
    more when it stops (`settle`).
    """

    def __init__(self, fixture: ForkFixture, shafts: Mapping[int, ForkShaft], *, update_ns: int) -> None:
        self.fixture = fixture
        self.shafts = dict(shafts)
        self.update_ns = int(update_ns)
        self._last_update_ns = 0

    @property
    def pushing(self) -> bool:
        """True while a fork is closed on the link and moving it (or holding it)."""
        return self.fixture.active is not None

    def close(self, component: int, now_ns: int) -> None:
        """Close fork `component` on the link; it pushes the link as its bender moves."""
        if component not in self.shafts:
            raise RuntimeError(f"this world has no fork on component {component}")
        self.fixture.engage(component, self.shafts[component].present_position_rad)
        self._last_update_ns = now_ns

    def follow(self, t_ns: int) -> None:
        """Re-pose the link after the active fork, at most every `update_ns`."""
        active = self.fixture.active
        if active is None or t_ns - self._last_update_ns < self.update_ns:
            return
        self._last_update_ns = t_ns
        self.fixture.update(self.shafts[active].present_position_rad)

    def settle(self) -> None:
        """The moving fork has stopped: the link follows it to its final angle, then the fork holds."""
        active = self.fixture.active
        if active is not None:
            self.fixture.update(self.shafts[active].present_position_rad)
            self.fixture.active = None

    def open(self) -> None:
        """Open every fork: the link is free (the trial may load it)."""
        self.settle()
        self.fixture.open_all()
