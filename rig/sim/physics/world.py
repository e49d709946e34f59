"""The simulated world: test article, winch line and bending fixture, integrated in virtual time.

`SimWorld` couples the physics of the rig to the byte-level device emulators through two small,
duck-typed hooks:

* **Servo shafts** (`ShaftLike`): any object with `present_position_rad` (output shaft, multi-turn,
  read each substep) and a settable `external_torque_nm`. The world reads the winch and, if there is
  one, the bender, and writes the line's torque on the winch (−tension·r_drum, see `winch_line.py`).
* **Device stepping**: `step_devices(t_ns)` (e.g. `EmulatedBus.advance_to`) lets the servos move
  up to `t_ns` under the torque written at the previous substep.

`advance_to(now_ns)` (registered as a `VirtualClock.on_advance` listener) integrates in fixed
substeps (1 ms by default; the last one may be shorter so that the world ends exactly at `now`).
Per substep, explicitly: the devices move; the bending fixture (if moving) updates the link; the
line tension follows from the winch angle and the acting point's take-up; that tension is recorded
(it is the tension *at* the substep's time); then friction acts: a joint whose criterion reaches its
static capacity starts to slip and turns at `slip_rate_rad_s` until its moment falls to the
kinetic level (`kinetic_ratio` × static), which slackens the line, and then sticks again, so a
winch that keeps reeling makes the tension rise to the next slip (stick-slip); finally the winch's
external torque is set from the tension after the slip motion.

All times are the shared clock's monotonic nanoseconds. `tension_at(t_ns)` interpolates the recorded
tension linearly over the last `history_s` seconds (the load-cell emulator's signal source).

**Slip kinds.** Each trial draws its kind from the preset's `slip_mix` (own random stream
`STREAM_SLIP_KIND`, so the other streams and a default run are unchanged): `sudden` (above);
`small_drop` (the same with a kinetic ratio of 1 − drop, drop 3-15 %); `creep` (at the static load the
joint yields slowly: each substep it turns just enough to hold the tension on a line that falls from
the peak by the creep's drop over its duration, then sticks with its full static capacity);
`stick_slip` (a train of drops, each a fraction of the tension at its onset, at the slip rate, the next
one after a dwell or as soon as the winch has re-tensioned the line to the train's first peak);
`other_joint` (joint estimation: a neighbouring joint of the fixture slips first, at a fraction of the
specimen's slip load: the line is relieved at once by the drop without the specimen moving, and
that joint is the one the configuration source names); `no_slip` (the trial's capacities are
multiplied by `no_slip_capacity_factor`, so the ramp reaches its force limit first). Every slip event
is a `SlipRecord` with its kind, its onset on the run clock and its load.

Trials: `begin_trial(kind, distance_m)` draws the capacities of this trial (each joint's true mean
capacity times an independent factor 1 + s·z, z ~ N(0, 1) clipped at ±3, where for a slip mass m of
that joint s = sqrt((a/m)² + b²), so that sd(m)² = a² + (b·m)²: multiplicative scatter has a = 0 and
s = b, additive b = 0; m is the joint's capacity over g times its lever arm in the configuration at
the trial's start, for the specimen the hook distance) and, for joint estimation, sets up
the **single-joint specimen**: one joint placed horizontally (its axis z along the base z, the line
pulling across it along the preset's direction without its z part), the hook at distance l, so the
lever arm is l. The
specimen is re-levelled (straight) at the start of every such trial. Link-validation trials use the
link in whatever configuration the fixture (or `set_configuration`) left it. Each slip is kept as a
`SlipRecord`; `truth()` returns the ground truth as a JSON-serialisable dict.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any, Protocol

import numpy as np

from model.joint import mu_delta0_pa_from_capacity, resolve_constant
from rig.sim.physics.article import ChainArticle
from rig.sim.physics.article_presets import (
    STREAM_BEND,
    STREAM_SLIP_KIND,
    STREAM_TRIAL_CAPACITY,
    SimPreset,
    stream_rng,
)
from rig.sim.physics.bending_fixture import BendingFixture
from rig.sim.physics.winch_line import WinchLine
from rig.vocabulary import SlipKind, TrialKind

DEFAULT_SUBSTEP_NS = 1_000_000
DEFAULT_HISTORY_S = 2.0
BEND_UPDATE_NS = 50_000_000  # how often a moving fixture re-poses the link (each re-pose costs ~0.2 ms)
MIN_CAPACITY_FACTOR = 0.05
TORSION_CRITERION = "sqrt((|N_bend|/cap)^2 + (N_torsion/(torsion_ratio*cap))^2) > 1"
TORSION_AXIS = "z axis of the joint's own frame {i} (the axis of component i)"


def specimen_direction(direction_w: Sequence[float]) -> tuple[float, float, float]:
    """The line direction across the horizontal specimen: `direction_w` without its z component.

    The specimen's axis is the base z axis, so this makes its lever arm exactly the hook distance;
    a direction along z (which could not load the specimen) falls back to (0, -1, 0).
    """
    x, y = float(direction_w[0]), float(direction_w[1])
    norm = math.hypot(x, y)
    return (x / norm, y / norm, 0.0) if norm > 1e-12 else (0.0, -1.0, 0.0)


class ShaftLike(Protocol):
    """What the world needs of an emulated servo: its output-shaft angle and an external-torque input."""

    external_torque_nm: float  # set by the world each substep [N·m, physical direction]

    @property
    def present_position_rad(self) -> float:
        """Output-shaft angle [rad], multi-turn, physical direction."""
        ...


@dataclass(frozen=True)
class SlipPlan:
    """The slip kind one trial drew and its parameters (None where the kind has none)."""

    kind: SlipKind
    drop_fraction: float | None = None  # small_drop, stick_slip (each drop), other_joint
    creep_duration_s: float | None = None
    creep_drop_fraction: float | None = None
    train_drops: int | None = None
    dwells_s: tuple[float, ...] = ()  # stick_slip: the dwell before each later drop
    other_joint: int | None = None  # the neighbouring joint (1-based, of the link) that slips
    other_load_n: float | None = None  # the tension at which it slips

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable copy."""
        out = asdict(self)
        out["dwells_s"] = list(self.dwells_s)
        if self.other_load_n is not None and not math.isfinite(self.other_load_n):
            out["other_load_n"] = None
        return out


@dataclass(slots=True)
class SlipRecord:
    """One true slip event: when, which joint (1-based), the tension it happened at, how it ended.

    `joint` is the article's joint (the specimen has one, joint 1); `moved_joint` is the link joint
    that moved, which the configuration source names: for a specimen slip the trial's specimen
    joint (1 for the nominal specimen), for an `other_joint` slip the neighbouring joint.
    `onset_time_ns` is the onset on the run clock (the clock the load-cell samples are stamped
    with); `peak_tension_n` is the slip load.
    """

    trial_index: int | None
    setup: str  # "link" or "specimen"
    joint: int
    onset_ns: int
    peak_tension_n: float  # recorded tension at the onset substep (the maximum before the drop)
    threshold_n: float  # the exact static slip load of the configuration at onset
    end_ns: int | None = None
    tension_after_n: float | None = None
    rotation_rad: float = 0.0
    kind: SlipKind = SlipKind.SUDDEN
    moved_joint: int = 0
    onset_time_ns: int | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable copy."""
        return asdict(self)


@dataclass(frozen=True)
class TrialTruth:
    """What was true for one trial: its capacities and the exact slip load at its start."""

    index: int  # 1-based, in begin_trial order
    kind: TrialKind
    distance_m: float | None
    specimen_joint: int | None  # joint estimation: the link joint used as the specimen (None: nominal)
    start_ns: int
    capacities_nm: tuple[float, ...]  # of the active setup (one entry for the specimen)
    capacity_factors: tuple[float, ...]
    slip_force_n: float  # static slip load of the configuration at begin_trial (inf: cannot slip)
    slip_mass_kg: float
    first_slip_joint: int  # 1-based, 0 if nothing can slip
    slip: SlipPlan = SlipPlan(SlipKind.SUDDEN)
    capacity_relative_sds: tuple[float, ...] = ()  # s of each capacity factor 1 + s·z

    def as_dict(self) -> dict[str, Any]:
        """JSON-serialisable copy (an infinite slip load becomes None)."""
        out = asdict(self)
        out["slip"] = self.slip.as_dict()
        out["slip_kind"] = self.slip.kind
        out["capacity_relative_sds"] = list(self.capacity_relative_sds)
        for key in ("slip_force_n", "slip_mass_kg"):
            if not math.isfinite(out[key]):
                out[key] = None
        out["capacities_nm"] = list(self.capacities_nm)
        out["capacity_factors"] = list(self.capacity_factors)
        return out


class SimWorld:
    """The rig's physics in virtual time; see the module docstring."""

    def __init__(
        self,
        preset: SimPreset,
        winch: ShaftLike,
        *,
        bender: ShaftLike | None = None,
        step_devices: Callable[[int], None] | None = None,
        devices_at_rest: Callable[[], bool] | None = None,
        seed: int = 0,
        start_ns: int = 0,
        substep_ns: int = DEFAULT_SUBSTEP_NS,
        history_s: float = DEFAULT_HISTORY_S,
        run_clock_offset_ns: int = 0,
    ) -> None:
        """`run_clock_offset_ns`: the run clock (`time_ns`) minus the world's monotonic time."""
        if not 10_000 <= substep_ns <= 10_000_000:
            raise ValueError(f"substep_ns = {substep_ns}; allowed: 10_000..10_000_000 (10 µs..10 ms)")
        if not history_s > 0:
            raise ValueError(f"history_s = {history_s}; allowed: > 0")
        self.preset = preset
        self.seed = int(seed)
        self._winch = winch
        self._bender = bender
        self.step_devices = step_devices
        # True when stepping the devices would move nothing until the load on them changes
        # (`ObjectServoBus.at_rest`); lets `advance_to` skip a still stretch in one go.
        self.devices_at_rest = devices_at_rest
        self._substep_ns = int(substep_ns)
        self._now_ns = int(start_ns)
        self._capacity_rng = stream_rng(seed, STREAM_TRIAL_CAPACITY)
        self._kind_rng = stream_rng(seed, STREAM_SLIP_KIND)
        self.run_clock_offset_ns = int(run_clock_offset_ns)

        self.link = ChainArticle(
            preset.segment_lengths_m,
            preset.point_m,
            preset.direction_w,
            preset.joint_capacities_nm,
            torsion_weak_joint=preset.torsion_weak_joint,
            torsion_ratio=preset.torsion_ratio,
        )
        self.specimen = ChainArticle(
            (0.0,),
            (0.0, 0.0, preset.joint_estimation_distances_m[0]),
            specimen_direction(preset.direction_w),
            (preset.specimen_capacity_nm,),
        )
        self._article = self.link
        self.line = WinchLine(
            preset.drum_radius_m,
            preset.line_stiffness_n_per_m,
            preset.spring_stiffness_n_per_m,
            slack_angle_rad=winch.present_position_rad + preset.winch_slack_rad,
        )
        self.fixture: BendingFixture | None = None
        if bender is not None:
            self.fixture = BendingFixture(
                preset.joint_count,
                rest_angle_rad=bender.present_position_rad,
                travel_per_bend=preset.bender_travel_per_bend,
                arrival_tolerance_rad=preset.bender_arrival_tolerance_rad,
                sigma_bend_rad=preset.sigma_bend_rad,
                rng=stream_rng(seed, STREAM_BEND),
            )
        self._last_bend_update_ns = self._now_ns

        self.trials: list[TrialTruth] = []
        self.slips: list[SlipRecord] = []
        self._slip: SlipRecord | None = None
        # The slip in progress beyond `_slip`: the kinetic ratio of a drop to the kinetic level, the
        # target tension of a stick-slip drop, the creep's line; the train and the other joint.
        self._slip_kinetic = preset.kinetic_ratio
        self._slip_target_n: float | None = None
        self._creep: tuple[int, int, float] | None = None  # (onset ns, duration ns, drop fraction)
        self._train_left = 0
        self._train_next_ns = 0
        self._train_peak_n = 0.0
        self._train_joint = 0
        self._other_load_n = math.inf  # the tension at which a neighbouring joint slips
        self._clamp_take_up_m = 0.0  # what an other-joint slip let the line in by

        self._history_len = int(history_s * 1e9 / self._substep_ns) + 16
        tension = self.line.tension_n(winch.present_position_rad, self._take_up_m())
        self._times_ns: list[int] = [self._now_ns]
        self._tensions_n: list[float] = [tension]
        winch.external_torque_nm = self.line.winch_torque_nm(tension)

    # --- state -------------------------------------------------------------------------------
    @property
    def now_ns(self) -> int:
        """The time (monotonic ns) the world has been integrated to."""
        return self._now_ns

    @property
    def tension_n(self) -> float:
        """The most recently recorded line tension [N]."""
        return self._tensions_n[-1]

    @property
    def setup(self) -> str:
        """Which article the line is hooked to: 'link' or 'specimen'."""
        return "link" if self._article is self.link else "specimen"

    @property
    def article(self) -> ChainArticle:
        """The article the line is hooked to."""
        return self._article

    @property
    def slipping(self) -> bool:
        """True while a joint is sliding."""
        return self._slip is not None

    @property
    def bending(self) -> bool:
        """True while the bending fixture is moving (and holding the link)."""
        return self.fixture is not None and self.fixture.moving

    def taut_winch_angle_rad(self) -> float:
        """The winch angle at which the line becomes taut in the present configuration (tests, scripts)."""
        return self.line.slack_angle_rad + self._take_up_m() / self.line.drum_radius_m

    def _take_up_m(self) -> float:
        """The line's take-up: the article's, plus a neighbouring joint's slip (joint estimation)."""
        return self._article.take_up_m + self._clamp_take_up_m

    @property
    def current_trial(self) -> TrialTruth | None:
        """The trial begun last, if any."""
        return self.trials[-1] if self.trials else None

    # --- time --------------------------------------------------------------------------------
    def advance_to(self, now_ns: int) -> None:
        """Integrate from the world's time to `now_ns` (monotonic) in substeps; a no-op if not later."""
        t_ns = self._now_ns
        step_ns = self._substep_ns
        step_devices, at_rest = self.step_devices, self.devices_at_rest
        winch, line = self._winch, self.line
        radius, slack, stiffness = line.drum_radius_m, line.slack_angle_rad, line.stiffness_n_per_m
        times, tensions, keep = self._times_ns, self._tensions_n, 2 * self._history_len
        last_theta = math.nan
        while t_ns < now_ns:
            t_ns = min(t_ns + step_ns, now_ns)
            fixture = self.fixture
            if self._slip is not None or self._train_left or (fixture is not None and fixture.moving):
                self._substep(t_ns)
                continue
            # Fast path of `_substep` for its common case (no slip under way, no stick-slip train
            # pending, the fixture still): the same steps in the same order, calls spelled out.
            if step_devices is not None:
                step_devices(t_ns)
            article = self._article
            theta = winch.present_position_rad
            stretch = radius * (theta - slack) - (article.take_up_m + self._clamp_take_up_m)
            tension = stiffness * stretch if stretch > 0.0 else 0.0  # WinchLine.tension_n
            times.append(t_ns)  # _record, spelled out
            tensions.append(tension)
            if len(times) > keep:
                self._trim_history()
            still = False
            if tension > self._other_load_n:
                tension = self._other_joint_slip(theta, tension, t_ns)
            elif tension > article.slip_threshold_n:
                self._start_slip(tension, t_ns)
                tension = self._continue_slip(theta, tension, (t_ns - self._now_ns) * 1e-9, t_ns)
            else:
                still = theta == last_theta  # the winch did not move (the cheap test first)
            last_theta = theta
            winch.external_torque_nm = -tension * radius
            self._now_ns = t_ns
            if still and t_ns < now_ns and at_rest is not None and step_devices is not None and at_rest():
                # Fast path: every servo is at rest (idle or settled under this very load), so each
                # remaining substep would move nothing and record this tension again. The servos
                # take their shortcut once, to `now_ns`; the history gets every substep's entry.
                step_devices(now_ns)
                for later_ns in (*range(t_ns + step_ns, now_ns, step_ns), now_ns):
                    self._record(later_ns, tension)
                self._now_ns = now_ns
                return

    def tension_at(self, t_ns: int) -> float:
        """Line tension [N] at monotonic `t_ns`, linearly interpolated; later than the world: the last value.

        Raises `ValueError` for a time older than the retained history (about `history_s`).
        """
        times = self._times_ns
        if t_ns >= times[-1]:
            return self._tensions_n[-1]
        if t_ns < times[0]:
            raise ValueError(f"t_ns = {t_ns} is older than the tension history (from {times[0]} ns)")
        i = bisect.bisect_right(times, t_ns)
        t0, t1 = times[i - 1], times[i]
        f0, f1 = self._tensions_n[i - 1], self._tensions_n[i]
        return f0 + (f1 - f0) * (t_ns - t0) / (t1 - t0)

    def tensions_at(self, times_ns: Sequence[int]) -> list[float]:
        """`tension_at` of each of the ascending `times_ns` (one batch: a load cell's samples of a tick).

        Fast path of `[self.tension_at(t) for t in times_ns]` with the same arithmetic, found by
        walking the history once instead of bisecting per time (tests/test_sim_fast_paths.py
        holds them equal).
        """
        times, tensions = self._times_ns, self._tensions_n
        if not times_ns:
            return []
        last_t = times[-1]
        first = times_ns[0]
        if first < times[0]:
            raise ValueError(f"t_ns = {first} is older than the tension history (from {times[0]} ns)")
        out: list[float] = []
        i = bisect.bisect_right(times, first) if first < last_t else len(times)
        count = len(times)
        for t_ns in times_ns:
            if t_ns >= last_t:
                out.append(tensions[-1])
                continue
            while i < count and times[i] <= t_ns:
                i += 1
            t0, t1 = times[i - 1], times[i]
            f0, f1 = tensions[i - 1], tensions[i]
            out.append(f0 + (f1 - f0) * (t_ns - t0) / (t1 - t0))
        return out

    def _substep(self, t_ns: int) -> None:
        dt_s = (t_ns - self._now_ns) * 1e-9
        if self.step_devices is not None:
            self.step_devices(t_ns)
        fixture = self.fixture
        holding = False
        if fixture is not None and fixture.moving:
            self._follow_fixture(fixture, t_ns)
            holding = fixture.moving and self._article is self.link
        article = self._article
        theta = self._winch.present_position_rad
        tension = self.line.tension_n(theta, article.take_up_m + self._clamp_take_up_m)
        self._record(t_ns, tension)
        if not holding:
            if self._slip is not None:
                if self._creep is None and self._slip_target_n is None:
                    tension = self._slide(theta, tension, dt_s, t_ns)  # sudden, small drop: the common case
                else:
                    tension = self._continue_slip(theta, tension, dt_s, t_ns)
            elif tension > self._other_load_n:
                tension = self._other_joint_slip(theta, tension, t_ns)
            elif tension > article.slip_threshold_n or (self._train_left and self._train_due(tension, t_ns)):
                self._start_slip(tension, t_ns)
                tension = self._continue_slip(theta, tension, dt_s, t_ns)
        self._winch.external_torque_nm = -tension * self.line.drum_radius_m
        self._now_ns = t_ns

    def _plan(self) -> SlipPlan:
        """The slip plan of the current trial (sudden before any trial)."""
        return self.trials[-1].slip if self.trials else SlipPlan(SlipKind.SUDDEN)

    def _moved_joint(self, article_joint: int) -> int:
        """The link joint that a slip of `article_joint` of the present article moves."""
        if self._article is self.link:
            return article_joint
        trial = self.current_trial
        return 1 if trial is None or trial.specimen_joint is None else trial.specimen_joint

    def _train_due(self, tension: float, t_ns: int) -> bool:
        """Whether the next drop of a stick-slip train starts now (dwell over, or re-tensioned)."""
        if self._train_left <= 0:
            return False
        if tension < 0.05 * self._train_peak_n:  # the line was unloaded: the train is over
            self._train_left = 0
            return False
        return t_ns >= self._train_next_ns or tension >= self._train_peak_n

    def _start_slip(self, tension: float, t_ns: int) -> None:
        """A slip of the article's governing joint starts now, of the trial's kind."""
        article = self._article
        plan = self._plan()
        kind = SlipKind(plan.kind)
        if kind in (SlipKind.OTHER_JOINT, SlipKind.NO_SLIP):
            kind = SlipKind.SUDDEN  # whatever still slips (after the other joint, or beyond 10x) is sudden
        joint = article.governing_joint
        self._slip_kinetic = self.preset.kinetic_ratio
        self._slip_target_n = None
        self._creep = None
        if kind is SlipKind.SMALL_DROP:
            assert plan.drop_fraction is not None
            self._slip_kinetic = 1.0 - plan.drop_fraction
        elif kind is SlipKind.CREEP:
            assert plan.creep_duration_s is not None and plan.creep_drop_fraction is not None
            self._creep = (t_ns, round(plan.creep_duration_s * 1e9), plan.creep_drop_fraction)
        elif kind is SlipKind.STICK_SLIP:
            assert plan.drop_fraction is not None and plan.train_drops is not None
            if self._train_left <= 0:  # the first drop of a new train
                self._train_left = plan.train_drops
                self._train_peak_n = tension
                self._train_joint = joint
            self._train_left -= 1
            self._slip_target_n = tension * (1.0 - plan.drop_fraction)
            joint = self._train_joint  # a train keeps slipping the joint it started with
        trial = self.trials[-1].index if self.trials else None
        self._slip = SlipRecord(
            trial_index=trial,
            setup=self.setup,
            joint=joint,
            onset_ns=t_ns,
            peak_tension_n=tension,
            threshold_n=article.slip_threshold_n,
            kind=kind,
            moved_joint=self._moved_joint(joint),
            onset_time_ns=t_ns + self.run_clock_offset_ns,
        )
        self.slips.append(self._slip)

    def _continue_slip(self, theta: float, tension: float, dt_s: float, t_ns: int) -> float:
        """Advance the slip in progress by one substep, by its kind; returns the tension after it."""
        if self._creep is not None:
            return self._creep_step(theta, tension, t_ns)
        if self._slip_target_n is not None:
            return self._drop_step(theta, tension, dt_s, t_ns, self._slip_target_n)
        return self._slide(theta, tension, dt_s, t_ns)

    def _rotation_for(self, joint: int, excess_n: float) -> tuple[np.ndarray, float] | None:
        """Axis and angle that lower the tension by `excess_n`; None if the joint cannot relieve it."""
        axis, take_up_per_rad = self._article.slip_flow(joint)
        if take_up_per_rad <= 0:
            return None
        return axis, excess_n / self.line.stiffness_n_per_m / take_up_per_rad

    def _drop_step(self, theta: float, tension: float, dt_s: float, t_ns: int, target_n: float) -> float:
        """One substep of a drop to `target_n` at the slip rate (stick-slip)."""
        record = self._slip
        assert record is not None
        if tension > target_n:
            turn = self._rotation_for(record.joint, tension - target_n)
            if turn is not None:
                axis, needed_rad = turn
                step_rad = min(needed_rad, self.preset.slip_rate_rad_s * dt_s)
                self._article.rotate_joint(record.joint, axis, step_rad)
                record.rotation_rad += step_rad
                tension = self.line.tension_n(theta, self._take_up_m())
                if step_rad < needed_rad:
                    return tension
        self._finish_slip(t_ns, tension)
        if self._train_left > 0:
            dwells = self._plan().dwells_s
            dwell_s = dwells[-self._train_left] if dwells else 0.0
            self._train_next_ns = t_ns + round(dwell_s * 1e9)
        return tension

    def _creep_step(self, theta: float, tension: float, t_ns: int) -> float:
        """One substep of creep: turn just enough to keep the tension on the creep's falling line."""
        record = self._slip
        assert record is not None and self._creep is not None
        onset_ns, duration_ns, drop = self._creep
        progress = min(1.0, (t_ns - onset_ns) / duration_ns)
        target_n = record.peak_tension_n * (1.0 - drop * progress)
        if tension > target_n:
            turn = self._rotation_for(record.joint, tension - target_n)
            if turn is not None:
                axis, needed_rad = turn
                self._article.rotate_joint(record.joint, axis, needed_rad)
                record.rotation_rad += needed_rad
                tension = self.line.tension_n(theta, self._take_up_m())
        if progress >= 1.0:
            self._finish_slip(t_ns, tension)
        return tension

    def _other_joint_slip(self, theta: float, tension: float, t_ns: int) -> float:
        """A neighbouring joint slips at once: the line is let in by the drop, the specimen stays."""
        trial = self.trials[-1]
        plan = trial.slip
        assert plan.drop_fraction is not None and plan.other_joint is not None
        self._other_load_n = math.inf
        record = SlipRecord(
            trial_index=trial.index,
            setup=self.setup,
            joint=plan.other_joint,
            onset_ns=t_ns,
            peak_tension_n=tension,
            threshold_n=tension,
            kind=SlipKind.OTHER_JOINT,
            moved_joint=plan.other_joint,
            onset_time_ns=t_ns + self.run_clock_offset_ns,
        )
        self.slips.append(record)
        self._clamp_take_up_m += tension * plan.drop_fraction / self.line.stiffness_n_per_m
        tension = self.line.tension_n(theta, self._take_up_m())
        record.end_ns = t_ns
        record.tension_after_n = tension
        return tension

    def _finish_slip(self, t_ns: int, tension: float) -> None:
        record = self._slip
        assert record is not None
        record.end_ns = t_ns
        record.tension_after_n = tension
        self._slip = None
        self._slip_target_n = None
        self._creep = None

    def _record(self, t_ns: int, tension_n: float) -> None:
        self._times_ns.append(t_ns)
        self._tensions_n.append(tension_n)
        if len(self._times_ns) > 2 * self._history_len:
            self._trim_history()

    def _trim_history(self) -> None:
        """Keep the last `_history_len` entries (in place: the lists stay the same objects)."""
        drop = len(self._times_ns) - self._history_len
        del self._times_ns[:drop]
        del self._tensions_n[:drop]

    def _slide(self, theta: float, tension: float, dt_s: float, t_ns: int) -> float:
        """Advance the current slip by one substep; returns the tension after it."""
        record = self._slip
        assert record is not None
        article = self._article
        joint = record.joint
        criterion = article.criterion_per_n(joint)
        kinetic = self._slip_kinetic
        if tension * criterion > kinetic:
            axis, take_up_per_rad = article.slip_flow(joint)
            if take_up_per_rad > 0:
                # First-order rotation that brings the moment down to the kinetic level.
                needed_rad = (tension - kinetic / criterion) / self.line.stiffness_n_per_m / take_up_per_rad
                step_rad = min(needed_rad, self.preset.slip_rate_rad_s * dt_s)
                article.rotate_joint(joint, axis, step_rad)
                record.rotation_rad += step_rad
                tension = self.line.tension_n(theta, article.take_up_m + self._clamp_take_up_m)
                if step_rad < needed_rad:
                    return tension
        self._finish_slip(t_ns, tension)
        return tension

    def _end_slip(self) -> None:
        if self._slip is not None:
            self._finish_slip(self._now_ns, self.tension_n)
        self._train_left = 0

    # --- bending -----------------------------------------------------------------------------
    def _follow_fixture(self, fixture: BendingFixture, t_ns: int) -> None:
        assert self._bender is not None
        angles, arrived = fixture.update(self._bender.present_position_rad)
        if angles is not None and (arrived or t_ns - self._last_bend_update_ns >= BEND_UPDATE_NS):
            self.link.set_joint_angles(angles)
            self._last_bend_update_ns = t_ns

    def request_bend(self, joint_angles_rad: Sequence[float]) -> float:
        """Ask the fixture for a planar configuration; returns the bender goal (rad) to command.

        The link is held by the fixture until the bender arrives within tolerance of that goal.
        """
        return self._request(joint_angles_rad, reset=False)

    def request_reset(self) -> float:
        """Ask the fixture to return the link to straight; returns the bender goal (rad) to command."""
        return self._request([0.0] * self.preset.joint_count, reset=True)

    def _request(self, joint_angles_rad: Sequence[float], *, reset: bool) -> float:
        if self.fixture is None or self._bender is None:
            raise RuntimeError("this world has no bender servo; use set_configuration instead")
        if self._article is self.link:
            self._end_slip()
        self._last_bend_update_ns = self._now_ns
        return self.fixture.request(
            joint_angles_rad, self.link.planar_joint_angles(), self._bender.present_position_rad, reset=reset
        )

    def set_configuration(self, joint_angles_rad: Sequence[float]) -> None:
        """Place the link in a planar configuration at once, exactly (an operator, or a test)."""
        if self._article is self.link:
            self._end_slip()
        self.link.set_joint_angles(joint_angles_rad)

    # --- trials ------------------------------------------------------------------------------
    def begin_trial(
        self, kind: TrialKind | str, distance_m: float | None = None, joint: int | None = None
    ) -> TrialTruth:
        """Start a trial: draw its capacities; for joint estimation hook the specimen at `distance_m`.

        For joint estimation, `joint` (1-based) makes the specimen that joint of the link (its true
        mean capacity); without it the specimen is the preset's nominal joint.
        """
        kind = TrialKind(kind)
        self._end_slip()
        preset = self.preset
        if kind is TrialKind.JOINT_ESTIMATION:
            if distance_m is None or not (math.isfinite(distance_m) and distance_m > 0):
                raise ValueError(f"joint estimation needs distance_m > 0; got {distance_m!r}")
            if joint is None:
                nominal = np.array([preset.specimen_capacity_nm])
            elif 1 <= joint <= preset.joint_count:
                nominal = np.array([preset.joint_capacities_nm[joint - 1]])
            else:
                raise ValueError(f"joint = {joint}; allowed: 1..{preset.joint_count} or None")
            self._article = self.specimen
            self.specimen.set_joint_angles([0.0])
            self.specimen.set_point((0.0, 0.0, float(distance_m)))
        else:
            if distance_m is not None or joint is not None:
                raise ValueError(
                    "link validation takes no distance_m or joint (the load point is the link's Q)"
                )
            nominal = np.asarray(preset.joint_capacities_nm)
            self._article = self.link
        self._other_load_n = math.inf
        self._clamp_take_up_m = 0.0
        draws = np.clip(self._capacity_rng.standard_normal(len(nominal)), -3.0, 3.0)
        if preset.scatter_a_kg == 0:
            relative_sds = np.full(len(nominal), preset.per_trial_capacity_sd)
            factors = np.maximum(1.0 + preset.per_trial_capacity_sd * draws, MIN_CAPACITY_FACTOR)
        else:
            # sd(m)/m with m = capacity / (g · lever arm): a·g·arm/capacity for the additive part.
            arms = np.asarray(self._article.lever_arms_m()[1:])
            additive = preset.scatter_a_kg * preset.g * arms / nominal
            relative_sds = np.sqrt(additive**2 + preset.per_trial_capacity_sd**2)
            factors = np.maximum(1.0 + relative_sds * draws, MIN_CAPACITY_FACTOR)
        plan = self._draw_plan(kind, joint)
        capacities = nominal * factors
        if plan.kind == SlipKind.NO_SLIP:
            capacities = capacities * preset.slip_mix.no_slip_capacity_factor
        self._article.set_capacities(capacities)
        threshold = self._article.slip_threshold_n
        if plan.kind == SlipKind.OTHER_JOINT:
            assert plan.other_load_n is not None
            self._other_load_n = plan.other_load_n * threshold  # inf if the specimen cannot slip
            plan = replace(plan, other_load_n=self._other_load_n)
        trial = TrialTruth(
            index=len(self.trials) + 1,
            kind=kind,
            distance_m=None if distance_m is None else float(distance_m),
            specimen_joint=joint,
            start_ns=self._now_ns,
            capacities_nm=self._article.capacities_nm,
            capacity_factors=tuple(float(f) for f in factors),
            slip_force_n=threshold,
            slip_mass_kg=threshold / preset.g,
            first_slip_joint=self._article.governing_joint,
            slip=plan,
            capacity_relative_sds=tuple(float(x) for x in relative_sds),
        )
        self.trials.append(trial)
        return trial

    def _draw_plan(self, kind: TrialKind, joint: int | None) -> SlipPlan:
        """Draw the trial's slip kind and its parameters from the slip-kind stream.

        For `other_joint`, `other_load_n` is still the fraction of the slip load (the caller scales it).
        """
        mix = self.preset.slip_mix
        rng = self._kind_rng
        u = float(rng.random())
        cumulative = np.cumsum(mix.probabilities)
        index = min(int(np.searchsorted(cumulative, u, side="right")), len(SlipKind) - 1)
        while mix.probabilities[index] == 0:  # u at the very top of the range: the last kind that can occur
            index -= 1
        slip_kind = list(SlipKind)[index]

        def uniform(bounds: tuple[float, float]) -> float:
            return float(rng.uniform(bounds[0], bounds[1]))

        if slip_kind is SlipKind.SMALL_DROP:
            return SlipPlan(slip_kind, drop_fraction=uniform(mix.small_drop_fraction))
        if slip_kind is SlipKind.CREEP:
            return SlipPlan(
                slip_kind,
                creep_duration_s=uniform(mix.creep_duration_s),
                creep_drop_fraction=uniform(mix.creep_drop_fraction),
            )
        if slip_kind is SlipKind.STICK_SLIP:
            low, high = (int(x) for x in mix.stick_slip_drops)
            drops = int(rng.integers(low, high + 1))
            return SlipPlan(
                slip_kind,
                drop_fraction=uniform(mix.stick_slip_drop_fraction),
                train_drops=drops,
                dwells_s=tuple(uniform(mix.stick_slip_dwell_s) for _ in range(drops - 1)),
            )
        if slip_kind is SlipKind.OTHER_JOINT:
            if kind is not TrialKind.JOINT_ESTIMATION:
                return SlipPlan(SlipKind.SUDDEN)  # every joint of the link is under test
            specimen = 1 if joint is None else joint
            count = self.preset.joint_count
            neighbour = specimen + 1 if specimen < count else specimen - 1  # 0: the clamp of a 1-joint link
            return SlipPlan(
                slip_kind,
                other_joint=neighbour,
                other_load_n=uniform(mix.other_joint_load_fraction),
                drop_fraction=uniform(mix.other_joint_drop_fraction),
            )
        return SlipPlan(slip_kind)

    # --- ground truth ------------------------------------------------------------------------
    def _trial_truth(self, trial: TrialTruth) -> dict[str, Any]:
        """One trial's truth with its slip events (onset on the run clock, kind, load, joint)."""
        out = trial.as_dict()
        out["slip_events"] = [
            {
                "onset_time_ns": s.onset_time_ns,
                "kind": s.kind,
                "load_n": s.peak_tension_n,
                "joint": s.moved_joint,
                "end_time_ns": None if s.end_ns is None else s.end_ns + self.run_clock_offset_ns,
                "tension_after_n": s.tension_after_n,
            }
            for s in self.slips
            if s.trial_index == trial.index
        ]
        return out

    def truth(self) -> dict[str, Any]:
        """Ground truth for the final comparison (JSON-serialisable; the runner logs it as `sim_truth`)."""
        p = self.preset
        constant = resolve_constant(p.constant)

        def joint_entry(capacity_nm: float) -> dict[str, float]:
            return {
                "capacity_nm": capacity_nm,
                "k_kg_m": capacity_nm / p.g,
                "mu_delta0_pa": float(mu_delta0_pa_from_capacity(capacity_nm, p.joint_radius_m, constant)),
            }

        return {
            "preset": p.name,
            "seed": self.seed,
            "article_seed": p.seed,
            "g": p.g,
            "constant": {"name": constant.name, "c": constant.value},
            "joint_radius_m": p.joint_radius_m,
            "joints": [{"joint": i + 1, **joint_entry(cap)} for i, cap in enumerate(p.joint_capacities_nm)],
            "specimen": joint_entry(p.specimen_capacity_nm),
            "noise": {
                "per_trial_capacity_sd": p.per_trial_capacity_sd,
                "loadcell_noise_n": p.loadcell_noise_n,
                "sigma_bend_rad": p.sigma_bend_rad,
                "sigma_meas_rad": p.sigma_meas_rad,
                "slipped_joint_report_probability": p.slipped_joint_report_probability,
            },
            "kinetic_ratio": p.kinetic_ratio,
            "scatter": {
                "shape": p.scatter_shape,
                "a_kg": p.scatter_a_kg,
                "b": p.per_trial_capacity_sd,
                "sd_m": "sqrt(a^2 + (b m)^2)",
            },
            "slip_mix": {
                "probabilities": dict(zip(SlipKind, p.slip_mix.probabilities, strict=True)),
                **{
                    k: list(v)
                    for k, v in asdict(p.slip_mix).items()
                    if isinstance(v, tuple) and k != "probabilities"
                },
                "other_joint_report_probability": p.slip_mix.other_joint_report_probability,
                "no_slip_capacity_factor": p.slip_mix.no_slip_capacity_factor,
            },
            "loadcell_artefacts": asdict(p.loadcell_artefacts),
            "run_clock_offset_ns": self.run_clock_offset_ns,
            "slip_rate_rad_s": p.slip_rate_rad_s if math.isfinite(p.slip_rate_rad_s) else None,
            "torsion": None
            if p.torsion_weak_joint is None
            else {
                "joint": p.torsion_weak_joint,
                "torsion_ratio": p.torsion_ratio,
                "axis": TORSION_AXIS,
                "criterion": TORSION_CRITERION,
            },
            "geometry": {
                "segment_lengths_m": list(p.segment_lengths_m),
                "point_m": list(p.point_m),
                "direction_w": list(p.unit_direction_w),
                "joint_estimation_distances_m": list(p.joint_estimation_distances_m),
            },
            "line": {
                "drum_radius_m": p.drum_radius_m,
                "line_stiffness_n_per_m": p.line_stiffness_n_per_m,
                "spring_stiffness_n_per_m": p.spring_stiffness_n_per_m,
                "effective_stiffness_n_per_m": self.line.stiffness_n_per_m,
                "winch_slack_rad": p.winch_slack_rad,
            },
            "substep_ns": self._substep_ns,
            "trials": [self._trial_truth(t) for t in self.trials],
            "slips": [s.as_dict() for s in self.slips],
        }


class WorldBendingFixture:
    """The runner's `BendingFixture` seam (rig.hw.session) over a world with one bender servo.

    `bend_goals` asks the world's fixture for the configuration and returns the goal to command;
    the world holds the link until the bender gets there.
    """

    def __init__(self, world: SimWorld, bender_id: int) -> None:
        self._world = world
        self._bender_id = bender_id

    def bend_goals(self, joint_angles_rad: tuple[float, ...]) -> dict[int, float]:
        """{bender id: goal [rad]} that sets `joint_angles_rad` (plus the fixture's placement error)."""
        return {self._bender_id: self._world.request_bend(joint_angles_rad)}

    def home_goals(self) -> dict[int, float]:
        """{bender id: goal [rad]} of the straight link."""
        return {self._bender_id: self._world.request_reset()}
