"""Bending by forks on named components (docs/bending.md): the bender goals that set a configuration.

A fork on component c travels along the base x axis by `r·Δθ` for a shaft turn Δθ (rack and pinion,
`bending.pinion_radius_m`). To set a target configuration the forks run one at a time, base to tip;
each pushes its component's contact point (o_{c+1}, or the acting point Q on the tip component) by
the x-distance between where it is and where the target puts it, the joints proximal to the fork's
segment being taken at their target angles (the forks before it set them). Geometry is the rig
config's, the present configuration the last measured one (straight after a reset).

The link does not simply take the commanded shape: the joints that yield, and by how much less than
the fork travelled, depend on their capacities (the contact deflects before a joint slips). So a
target is reached by bending, measuring, and correcting: a correction pushes each fork whose segment
is off by more than the tolerance by the remaining distance plus what that fork fell short by last
time (its shortfall, learned from the measurements), at most `max_corrections` times.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from model.chain import forward_kinematics, planar_transforms
from rig.inputs.rig_config import RigConfig, configuration_source_kind
from rig.vocabulary import ConfigurationSourceKind


@dataclass(frozen=True, slots=True)
class BendStage:
    """One fork's move: its servo, its component and the shaft goal [rad]."""

    servo_id: int
    component: int
    goal_rad: float


class ForkBending:
    """The goals of forks on named components (servo id -> component); see the module docstring."""

    def __init__(
        self,
        forks: Mapping[int, int],
        segment_lengths_m: Sequence[float],
        point_m: Sequence[float],
        pinion_radius_m: float,
    ) -> None:
        self.forks = dict(sorted(forks.items(), key=lambda item: item[1]))  # base to tip
        self._lengths = np.asarray(segment_lengths_m, dtype=float)
        self._point = np.asarray(point_m, dtype=float)
        self.pinion_radius_m = float(pinion_radius_m)
        self.joint_count = len(self._lengths)
        self._home: dict[int, float] = {}
        self._pushed_m: dict[int, float] = {}  # each fork's last commanded push
        self._expected_m: dict[int, tuple[float, tuple[float, ...]]] = {}  # (x before, angles before)
        self.shortfall_m: dict[int, float] = {}

    def segment(self, component: int) -> range:
        """The joints fork `component` moves: after the nearest proximal fork, up to it."""
        held = [c for c in self.forks.values() if c < component]
        return range((max(held) if held else 0) + 1, component + 1)

    def contact_x_m(self, angles_rad: Sequence[float] | np.ndarray, component: int) -> float:
        """X (base frame) of component `component`'s contact point in a planar configuration."""
        poses = forward_kinematics(planar_transforms(np.asarray(angles_rad, dtype=float), self._lengths))
        if component < self.joint_count:
            return float(poses[component + 1, 0, 3])
        tip = poses[-1]
        return float(tip[0, :3] @ self._point + tip[0, 3])

    def bend_stages(
        self,
        target_rad: Sequence[float],
        present_rad: Sequence[float],
        positions_rad: Mapping[int, float],
        *,
        tolerance_rad: float = 0.0,
        correcting: bool = False,
    ) -> list[BendStage]:
        """The forks' moves, base to tip, from `present_rad` toward `target_rad` (skipping forks on target).

        `correcting`: the present configuration is measured after an earlier bend; each fork's
        shortfall then is learned and added to its push.
        """
        for sid, position in positions_rad.items():
            self._home.setdefault(sid, position)
        target = np.asarray(target_rad, dtype=float)
        present = np.asarray(present_rad, dtype=float)
        out: list[BendStage] = []
        for sid, component in self.forks.items():
            joints = [j - 1 for j in self.segment(component)]
            if correcting and sid in self._expected_m:
                self._learn(sid, component, present)
            if max(abs(target[j] - present[j]) for j in joints) <= tolerance_rad:
                continue
            before = target.copy()
            before[joints] = present[joints]
            before[component:] = present[component:]
            push = self.contact_x_m(target, component) - self.contact_x_m(before, component)
            shortfall = self.shortfall_m.get(sid, 0.0) if correcting else 0.0
            push += float(np.sign(push)) * max(shortfall, 0.0)
            self._pushed_m[sid] = push
            self._expected_m[sid] = (self.contact_x_m(before, component), tuple(before))
            goal = positions_rad[sid] + push / self.pinion_radius_m
            out.append(BendStage(sid, component, goal))
        return out

    def _learn(self, sid: int, component: int, measured: np.ndarray) -> None:
        """How far fork `sid` fell short of its last push, from the measured configuration."""
        x_before, angles_before = self._expected_m[sid]
        reached = np.asarray(angles_before, dtype=float)
        joints = [j - 1 for j in self.segment(component)]
        reached[joints] = measured[joints]
        achieved = self.contact_x_m(reached, component) - x_before
        pushed = self._pushed_m[sid]
        if pushed != 0.0:
            self.shortfall_m[sid] = max(0.0, abs(pushed) - float(np.sign(pushed)) * achieved)

    def home_goals(self) -> dict[int, float]:
        """Every fork back to where it started (the link is straightened against the guide bar)."""
        return dict(self._home)

    def begin_stage(self, stage: BendStage) -> None:
        """The fork's jaws close on its component mechanically (nothing to command)."""

    def end_stage(self, stage: BendStage) -> None:
        """The fork holds where it stopped (nothing to command)."""

    def end_bend(self) -> None:
        """The forks open when their benders stop pushing (nothing to command)."""


class ManualBending:
    """No forks: the operator bends the link by hand after a prompt (then it is measured)."""

    def bend_stages(
        self,
        target_rad: Sequence[float],
        present_rad: Sequence[float],
        positions_rad: Mapping[int, float],
        *,
        tolerance_rad: float = 0.0,
        correcting: bool = False,
    ) -> list[BendStage]:
        """No servo moves: the runner asks the operator."""
        return []

    def begin_stage(self, stage: BendStage) -> None:
        """Nothing to do."""

    def end_stage(self, stage: BendStage) -> None:
        """Nothing to do."""

    def end_bend(self) -> None:
        """Nothing to do."""

    def home_goals(self) -> dict[int, float]:
        """No servo goals: the runner asks the operator."""
        return {}


def fork_components(config: RigConfig) -> dict[int, int]:
    """Servo id -> component of every bender that names one (empty: bending is by hand)."""
    return {s.servo_id: s.component for s in config.servos.benders if s.component is not None}


def unreached_joints(
    forks: Mapping[int, int], target_rad: Sequence[float], tolerance_rad: float
) -> tuple[int, ...]:
    """The joints (1-based) a target bends beyond `tolerance_rad` that no fork reaches.

    A fork's push reaches only the joints up to its own component, so the joints beyond the most
    distal fork stay as the reset left them (straight). Without forks nothing is unreached: the
    operator's hands reach every joint.
    """
    if not forks:
        return ()
    last = max(forks.values())
    return tuple(j for j, angle in enumerate(target_rad, start=1) if j > last and abs(angle) > tolerance_rad)


def unreached_warning(
    config: RigConfig, configuration_index: int | None, target_rad: Sequence[float], tolerance_rad: float
) -> str | None:
    """The warning for a target that bends joints no fork of `config` reaches (None when the forks reach it).

    The run goes on with those joints as they are; the text says so and what the prediction then uses.
    """
    forks = fork_components(config)
    joints = unreached_joints(forks, target_rad, tolerance_rad)
    if not joints:
        return None
    listed = ", ".join(str(j) for j in joints)
    components = ", ".join(str(c) for c in sorted(forks.values()))
    if configuration_source_kind(config) == ConfigurationSourceKind.COMMAND:
        prediction = (
            "nothing measures the link (configuration.source: command), so the prediction wrongly "
            "takes them as bent"
        )
    else:
        prediction = "the prediction uses the measured configuration"
    return (
        f"configuration {configuration_index} bends joint{'s' if len(joints) > 1 else ''} {listed}, which no "
        f"fork of {config.source} reaches (forks on component{'s' if len(forks) > 1 else ''} {components}): "
        f"they are left as they are (straight after the reset) and {prediction}; to bend them, put forks "
        f"on the components up to {joints[-1]} (servos.ids[N].component), or bend by hand with a rig "
        "config whose benders name no component (docs/bending.md)"
    )


def config_fixture(config: RigConfig) -> ForkBending | ManualBending:
    """The fixture a rig config describes: forks where its benders name components, else by hand."""
    forks = fork_components(config)
    if not forks:
        return ManualBending()
    article = config.article
    return ForkBending(forks, article.segment_lengths_m, article.point_m, config.bending.pinion_radius_m)
