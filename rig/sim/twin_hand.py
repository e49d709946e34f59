"""The twin's simulated hand: between trials, while the line is slack, it sets the world up for the next.

Over the ports (`rig sim rig`) the runner cannot tell the world that a trial begins, so the person at
the rig does it, as a careful person would on the bench: the hand starts with the first trial of
the protocol it was given set up, and moves on to the next trial once the present one is over and
the line has been slack for `SLACK_DWELL_S`. A trial is over when one of its joints slipped, or when
the line reached the protocol's ramp limit `max_force_n` without a slip. Setting a trial up is what
the in-process simulated person does when the runner asks: for joint estimation it hooks the line
to the specimen at the trial's distance; for link validation it straightens the link and bends it
by hand to the trial's configuration (with its placement error). The world draws the trial's
capacities itself when the line is next loaded (a fresh static friction after the re-stick).

The hand follows the protocol's fixed trials in the order the run plans them with the same seed;
after the last it keeps setting up the last one again. Without a protocol it sets up a
link-validation trial on the straight link, again after every one. Forks (benders that name a
component) are served on the bus, but the twin does not close them on the link: a link-validation
trial is bent by the hand. Not verified against a person at a real rig.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from rig.errors import InputError
from rig.inputs.protocol import Protocol
from rig.sim.physics.world import SimWorld
from rig.vocabulary import TrialKind

SLACK_N = 0.05  # the line counts as slack at or below this tension
SLACK_DWELL_S = 0.3  # a careful person waits this long with the line slack before touching the rig


@dataclass(frozen=True)
class HandTrial:
    """What the hand sets up for one trial."""

    kind: TrialKind
    distance_m: float | None = None  # joint estimation: where the hook goes
    joint: int | None = None  # joint estimation: the link joint the specimen is
    joint_angles_rad: tuple[float, ...] | None = None  # link validation: the bend, by hand


def hand_trials(protocol: Protocol) -> list[HandTrial]:
    """The protocol's trials in run order, as the hand sets them up (adaptive blocks are refused)."""
    if protocol.adaptive:
        raise InputError(
            f"--protocol {protocol.source}: design: adaptive; allowed: fixed blocks only (the twin's hand "
            "cannot know the distances the planner will choose)"
        )
    return [
        HandTrial(t.kind, distance_m=t.distance_m, joint=t.joint, joint_angles_rad=t.joint_angles_rad)
        for t in sorted(protocol.trials, key=lambda t: t.trial_id)
    ]


class TwinHand:
    """Sets up each trial in turn while the line is slack; a clock listener (`advance_to`)."""

    def __init__(
        self, world: SimWorld, trials: Sequence[HandTrial] = (), *, done_force_n: float = float("inf")
    ) -> None:
        self.world = world
        self.trials = list(trials) or [HandTrial(TrialKind.LINK_VALIDATION)]
        self.done_force_n = done_force_n
        self.index = -1  # into `trials`: the trial set up last
        self._slips_before = 0  # the world's slip count when the present trial was set up
        self._over = False  # the present trial slipped or reached done_force_n
        self._slack_since_ns: int | None = None
        self.set_up_next()

    def set_up_next(self) -> None:
        """Set up the next trial (the last one again once the list is done)."""
        self.set_up(min(self.index + 1, len(self.trials) - 1))

    def set_up(self, index: int) -> HandTrial:
        """Set up trial `index` (0-based in `trials`) and go on from it: the person follows a prompt.

        When the run repeats a trial (it recovered from a fault), the hand has moved on already; the
        person at the twin's console puts it back (`trial N`).
        """
        if not 0 <= index < len(self.trials):
            raise ValueError(f"allowed: 1-{len(self.trials)}")
        self.index = index
        trial = self.trials[index]
        world = self.world
        match trial.kind:
            case TrialKind.JOINT_ESTIMATION:
                assert trial.distance_m is not None  # every joint-estimation trial has one
                world.place_hook(trial.distance_m, trial.joint)
            case TrialKind.LINK_VALIDATION:
                world.straighten()
                if trial.joint_angles_rad is not None:
                    world.bend_by_hand(trial.joint_angles_rad)
        self._slips_before = len(world.slips)
        self._over = False
        self._slack_since_ns = None
        return trial

    def advance_to(self, now_ns: int) -> None:
        """Watch the line: once the present trial is over and the line has stayed slack, set up the next."""
        world = self.world
        if not self._over:
            self._over = len(world.slips) > self._slips_before or world.tension_n >= self.done_force_n
            if not self._over:
                return
        if world.tension_n > SLACK_N:
            self._slack_since_ns = None
            return
        if self._slack_since_ns is None:
            self._slack_since_ns = now_ns
        if now_ns - self._slack_since_ns >= SLACK_DWELL_S * 1e9:
            self.set_up_next()
