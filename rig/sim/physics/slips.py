"""How the simulated joints slip: one object per slip kind, with its own state and substep.

A trial's `SlipBehaviour` (made from the `SlipPlan` it drew, `behaviour_for`) decides what happens
when the line's tension reaches the article's slip load: it opens a `SlipRecord` and returns the
`ActiveSlip` that the world then steps once per substep until it is done:

* `Sudden` / `SmallDrop` -> `KineticSlide`: the joint turns at the slip rate until its moment is
  down to the kinetic level (the preset's `kinetic_ratio` x static, or 1 - the drawn drop).
* `Creep` -> `CreepSlide`: the joint turns just enough to hold the tension on a line falling from
  the peak by the creep's drop over its duration, then sticks.
* `StickSlip` -> `TrainDrop`: each drop falls by a fraction of its onset tension at the slip rate;
  the train (its own state: drops left, first peak, next due time, joint) starts the next drop
  after a dwell or as soon as the winch has re-tensioned the line to the first peak.
* `OtherJoint`: a neighbouring joint slips at once at a fraction of the specimen's slip load (the
  line is let in by the drop, the specimen stays); whatever slips later is sudden.
* `NoSlip`: the capacities were multiplied at the draw; whatever still slips is sudden.

The world (`SlipHost`) owns the article, the line and the list of records; these objects only
hold what the slip in progress or the trial's kind needs to remember.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol, assert_never

import numpy as np

from rig.sim.kinds import SlipKind
from rig.sim.physics.link import ChainLink
from rig.sim.physics.winch_line import WinchLine
from rig.sim.truth import SlipPlan, SlipTruth


@dataclass(slots=True)
class SlipRecord:
    """One true slip event as it happens: its onset, and what the world fills in until it ends.

    `onset` holds every field of the slip (`rig.sim.truth.SlipTruth`) as it began; the three that
    change while the joint turns are kept here and put into the copy that `truth()` returns.
    """

    onset: SlipTruth  # end_ns, tension_after_n and rotation_rad at their defaults
    end_ns: int | None = None
    tension_after_n: float | None = None
    rotation_rad: float = 0.0

    def truth(self) -> SlipTruth:
        """The record as it stands now."""
        return replace(
            self.onset,
            end_ns=self.end_ns,
            tension_after_n=self.tension_after_n,
            rotation_rad=self.rotation_rad,
        )


class SlipHost(Protocol):
    """What a slip needs of the world: the hooked article, the line, the slip rate, the records."""

    line: WinchLine

    @property
    def article(self) -> ChainLink:
        """The article the line is hooked to."""
        ...

    @property
    def slip_rate_rad_s(self) -> float:
        """How fast a slipping joint turns."""
        ...

    def line_take_up_m(self) -> float:
        """The line's take-up now (the article's and a neighbouring joint's)."""
        ...

    def open_slip(
        self,
        joint: int,
        tension_n: float,
        threshold_n: float,
        kind: SlipKind,
        t_ns: int,
        moved_joint: int | None = None,
    ) -> SlipRecord:
        """Record the onset of a slip of `joint` (`moved_joint` None: the link joint the article's moves)."""
        ...

    def let_line_in(self, length_m: float) -> None:
        """A joint outside the article turned: the line's take-up grows by `length_m`."""
        ...


def _relief(
    article: ChainLink, joint: int, excess_n: float, stiffness: float
) -> tuple[np.ndarray, float] | None:
    """Axis and angle that lower the tension by `excess_n`; None if the joint cannot relieve it."""
    axis, take_up_per_rad = article.slip_flow(joint)
    if take_up_per_rad <= 0:
        return None
    return axis, excess_n / stiffness / take_up_per_rad


# --- a slip under way ---------------------------------------------------------------------------
class ActiveSlip:
    """A slip in progress: `step` advances it by one substep and returns the tension after it."""

    __slots__ = ("done", "record")

    def __init__(self, record: SlipRecord) -> None:
        self.record = record
        self.done = False

    def step(self, host: SlipHost, theta: float, tension: float, dt_s: float, t_ns: int) -> float:
        """One substep; sets `done` (and the record's end) when the joint sticks again."""
        raise NotImplementedError

    def finish(self, t_ns: int, tension: float) -> None:
        """The joint sticks again (or the slip is cut short) at `t_ns` with the line at `tension`."""
        self.record.end_ns = t_ns
        self.record.tension_after_n = tension
        self.done = True


class KineticSlide(ActiveSlip):
    """Sudden and small drops: turn at the slip rate until the moment is down to `kinetic` x static."""

    __slots__ = ("kinetic",)

    def __init__(self, record: SlipRecord, kinetic: float) -> None:
        super().__init__(record)
        self.kinetic = kinetic

    def step(self, host: SlipHost, theta: float, tension: float, dt_s: float, t_ns: int) -> float:
        """One substep of the slide."""
        record = self.record
        article = host.article
        joint = record.onset.joint
        criterion = article.criterion_per_n(joint)
        kinetic = self.kinetic
        if tension * criterion > kinetic:
            axis, take_up_per_rad = article.slip_flow(joint)
            if take_up_per_rad > 0:
                # First-order rotation that brings the moment down to the kinetic level.
                line = host.line
                needed_rad = (tension - kinetic / criterion) / line.stiffness_n_per_m / take_up_per_rad
                step_rad = min(needed_rad, host.slip_rate_rad_s * dt_s)
                article.rotate_joint(joint, axis, step_rad)
                record.rotation_rad += step_rad
                tension = line.tension_n(theta, host.line_take_up_m())
                if step_rad < needed_rad:
                    return tension
        self.finish(t_ns, tension)
        return tension


class CreepSlide(ActiveSlip):
    """Creep: hold the tension on the line from the peak down by `drop` over `duration_ns`, then stick."""

    __slots__ = ("drop", "duration_ns", "onset_ns")

    def __init__(self, record: SlipRecord, onset_ns: int, duration_ns: int, drop: float) -> None:
        super().__init__(record)
        self.onset_ns = onset_ns
        self.duration_ns = duration_ns
        self.drop = drop

    def step(self, host: SlipHost, theta: float, tension: float, dt_s: float, t_ns: int) -> float:
        """One substep: turn just enough to keep the tension on the creep's falling line."""
        record = self.record
        progress = min(1.0, (t_ns - self.onset_ns) / self.duration_ns)
        target_n = record.onset.peak_tension_n * (1.0 - self.drop * progress)
        if tension > target_n:
            line = host.line
            turn = _relief(host.article, record.onset.joint, tension - target_n, line.stiffness_n_per_m)
            if turn is not None:
                axis, needed_rad = turn
                host.article.rotate_joint(record.onset.joint, axis, needed_rad)
                record.rotation_rad += needed_rad
                tension = line.tension_n(theta, host.line_take_up_m())
        if progress >= 1.0:
            self.finish(t_ns, tension)
        return tension


class TrainDrop(ActiveSlip):
    """One drop of a stick-slip train: down to `target_n` at the slip rate; then the train's dwell."""

    __slots__ = ("target_n", "train")

    def __init__(self, record: SlipRecord, target_n: float, train: StickSlip) -> None:
        super().__init__(record)
        self.target_n = target_n
        self.train = train

    def step(self, host: SlipHost, theta: float, tension: float, dt_s: float, t_ns: int) -> float:
        """One substep of the drop."""
        record = self.record
        target_n = self.target_n
        if tension > target_n:
            line = host.line
            turn = _relief(host.article, record.onset.joint, tension - target_n, line.stiffness_n_per_m)
            if turn is not None:
                axis, needed_rad = turn
                step_rad = min(needed_rad, host.slip_rate_rad_s * dt_s)
                host.article.rotate_joint(record.onset.joint, axis, step_rad)
                record.rotation_rad += step_rad
                tension = line.tension_n(theta, host.line_take_up_m())
                if step_rad < needed_rad:
                    return tension
        self.finish(t_ns, tension)
        self.train.drop_ended(t_ns)
        return tension


# --- a trial's slip kind -------------------------------------------------------------------------
class SlipBehaviour:
    """What a trial's joint does at its slip load; the base slips suddenly to the preset's kinetic level.

    `pending` is True while the kind has something to check even below the slip load (a stick-slip
    train's next drop), and `other_load_n` is the tension at which a neighbouring joint slips first
    (infinite for every other kind): the world's fast substep runs only when neither can act.
    """

    kind = SlipKind.SUDDEN

    def __init__(self, plan: SlipPlan, kinetic_ratio: float) -> None:
        self.plan = plan
        self.kinetic_ratio = kinetic_ratio
        self.pending = False
        self.other_load_n = math.inf

    def start(self, host: SlipHost, tension: float, t_ns: int) -> ActiveSlip:
        """The article's governing joint starts to slip now."""
        article = host.article
        record = host.open_slip(
            article.governing_joint, tension, article.slip_threshold_n, SlipKind.SUDDEN, t_ns
        )
        return KineticSlide(record, self.kinetic_ratio)

    def due(self, tension: float, t_ns: int) -> bool:
        """Whether a slip starts now below the slip load (the next drop of a train)."""
        return False

    def end(self) -> None:
        """The slip in progress was cut short (a new trial, the link re-posed): forget what is pending."""
        self.pending = False

    def slip_other_joint(self, host: SlipHost, theta: float, tension: float, t_ns: int) -> float:
        """A neighbouring joint slips at once (only `OtherJoint` has one)."""
        raise RuntimeError(f"a {self.kind} trial has no other joint to slip")


class Sudden(SlipBehaviour):
    """The joint turns until its moment is `kinetic_ratio` x static."""


class NoSlip(SlipBehaviour):
    """The capacities were multiplied at the draw (the ramp reaches its limit first); beyond, sudden."""

    kind = SlipKind.NO_SLIP


class SmallDrop(SlipBehaviour):
    """A sudden slip with a small drop: the kinetic level is 1 - the drawn drop fraction."""

    kind = SlipKind.SMALL_DROP

    def start(self, host: SlipHost, tension: float, t_ns: int) -> ActiveSlip:
        """A slide to 1 - drop of the static level."""
        assert self.plan.drop_fraction is not None
        article = host.article
        record = host.open_slip(
            article.governing_joint, tension, article.slip_threshold_n, SlipKind.SMALL_DROP, t_ns
        )
        return KineticSlide(record, 1.0 - self.plan.drop_fraction)


class Creep(SlipBehaviour):
    """At the static load the joint yields slowly over the drawn duration."""

    kind = SlipKind.CREEP

    def start(self, host: SlipHost, tension: float, t_ns: int) -> ActiveSlip:
        """A creep from now."""
        plan = self.plan
        assert plan.creep_duration_s is not None and plan.creep_drop_fraction is not None
        article = host.article
        record = host.open_slip(
            article.governing_joint, tension, article.slip_threshold_n, SlipKind.CREEP, t_ns
        )
        return CreepSlide(record, t_ns, round(plan.creep_duration_s * 1e9), plan.creep_drop_fraction)


class StickSlip(SlipBehaviour):
    """A train of drops on one joint: each after a dwell, or once the line is back at the first peak."""

    kind = SlipKind.STICK_SLIP

    def __init__(self, plan: SlipPlan, kinetic_ratio: float) -> None:
        super().__init__(plan, kinetic_ratio)
        self.drops_left = 0
        self.next_ns = 0
        self.peak_n = 0.0
        self.joint = 0

    def start(self, host: SlipHost, tension: float, t_ns: int) -> ActiveSlip:
        """The next drop of the train, or the first of a new one."""
        plan = self.plan
        assert plan.drop_fraction is not None and plan.train_drops is not None
        article = host.article
        joint = article.governing_joint
        if self.drops_left <= 0:  # the first drop of a new train
            self.drops_left = plan.train_drops
            self.peak_n = tension
            self.joint = joint
        self.drops_left -= 1
        self.pending = self.drops_left != 0
        target_n = tension * (1.0 - plan.drop_fraction)
        # A train keeps slipping the joint it started with.
        record = host.open_slip(self.joint, tension, article.slip_threshold_n, SlipKind.STICK_SLIP, t_ns)
        return TrainDrop(record, target_n, self)

    def drop_ended(self, t_ns: int) -> None:
        """A drop is over: the next one is due after its dwell."""
        if self.drops_left > 0:
            dwells = self.plan.dwells_s
            dwell_s = dwells[-self.drops_left] if dwells else 0.0
            self.next_ns = t_ns + round(dwell_s * 1e9)

    def due(self, tension: float, t_ns: int) -> bool:
        """Whether the next drop starts now (dwell over, or re-tensioned); an unloaded line ends the train."""
        if self.drops_left <= 0:
            return False
        if tension < 0.05 * self.peak_n:  # the line was unloaded: the train is over
            self.drops_left = 0
            self.pending = False
            return False
        return t_ns >= self.next_ns or tension >= self.peak_n

    def end(self) -> None:
        """Forget the train."""
        self.drops_left = 0
        self.pending = False


class OtherJoint(SlipBehaviour):
    """A neighbouring joint slips first, at `plan.other_load_n`; whatever slips after it is sudden."""

    kind = SlipKind.OTHER_JOINT

    def __init__(self, plan: SlipPlan, kinetic_ratio: float) -> None:
        super().__init__(plan, kinetic_ratio)
        assert plan.other_load_n is not None
        self.other_load_n = plan.other_load_n

    def slip_other_joint(self, host: SlipHost, theta: float, tension: float, t_ns: int) -> float:
        """The line is let in by the drop at once, the specimen stays; returns the tension after it."""
        plan = self.plan
        assert plan.drop_fraction is not None and plan.other_joint is not None
        self.other_load_n = math.inf
        record = host.open_slip(
            plan.other_joint, tension, tension, SlipKind.OTHER_JOINT, t_ns, plan.other_joint
        )
        host.let_line_in(tension * plan.drop_fraction / host.line.stiffness_n_per_m)
        tension = host.line.tension_n(theta, host.line_take_up_m())
        record.end_ns = t_ns
        record.tension_after_n = tension
        return tension


def behaviour_for(plan: SlipPlan, kinetic_ratio: float) -> SlipBehaviour:
    """The slip behaviour of a trial that drew `plan` (its `other_load_n`, if any, already in N)."""
    kind = plan.kind
    match kind:
        case SlipKind.SUDDEN:
            return Sudden(plan, kinetic_ratio)
        case SlipKind.SMALL_DROP:
            return SmallDrop(plan, kinetic_ratio)
        case SlipKind.CREEP:
            return Creep(plan, kinetic_ratio)
        case SlipKind.STICK_SLIP:
            return StickSlip(plan, kinetic_ratio)
        case SlipKind.OTHER_JOINT:
            return OtherJoint(plan, kinetic_ratio)
        case SlipKind.NO_SLIP:
            return NoSlip(plan, kinetic_ratio)
        case _:
            assert_never(kind)
