"""The simulated world: test article, winch line and the forks that bend it, integrated in virtual time.

`SimWorld` couples the physics of the rig to the byte-level device emulators through two small,
duck-typed hooks:

* **Servo shafts** (`ShaftLike`): any object with `present_position_rad` (output shaft, multi-turn,
  read each substep) and a settable `external_torque_nm`. The world reads the winch and the
  forks' benders, and writes the line's torque on the winch (−tension·r_drum, see `winch_line.py`).
* **Device stepping**: `step_devices(t_ns)` (e.g. `EmulatedBus.advance_to`) lets the servos move
  up to `t_ns` under the torque written at the previous substep.

`advance_to(now_ns)` (registered as a `VirtualClock.on_advance` listener) integrates in fixed
substeps (1 ms by default; the last one may be shorter so that the world ends exactly at `now`).
Per substep, explicitly: the devices move; a pushing fork (forks.py) moves the link; the
line tension follows from the winch angle and the acting point's take-up; that tension is recorded
(it is the tension *at* the substep's time); then friction acts: a joint whose criterion reaches its
static capacity starts to slip and turns at `slip_rate_rad_s` until its moment falls to the
kinetic level (`kinetic_ratio` × static), which slackens the line, and then sticks again, so a
winch that keeps reeling makes the tension rise to the next slip (stick-slip); finally the winch's
external torque is set from the tension after the slip motion.

All times are the shared clock's monotonic nanoseconds. `tension_at(t_ns)` interpolates the recorded
tension linearly over the last `history_s` seconds (the load cells' signal; `tension_history.py`).

**Slip kinds.** Each trial draws its kind and its capacities (`trial_draws.py`, each on its own
random stream of the seed); the kind becomes the trial's `SlipBehaviour` (`slips.py`: sudden, small
drop, creep, stick-slip train, other joint first, no slip), which opens the slip at the slip load and
steps it until the joint sticks again. Every slip event is a `SlipRecord` with its kind, its onset on
the run clock and its load.

**Trials come from what is done to the rig**, not from the runner. The simulated person hooks
the line to the **single-joint specimen** (`place_hook(distance_m, joint)`: one joint held
horizontally, its axis z along the base z, the line pulling across it along the preset's direction
without its z part, the hook at distance l, so the lever arm is l; the specimen re-levelled) or to
the link (`hook_link`, also what bending the link by hand or by the forks does). Each of those, and a
re-stick (the line slack for `RESTICK_S` after a slip), makes the joints' static friction **fresh**:
the next time the line becomes taut the world draws that loading's capacities and slip kind
(`draw_trial`), one `TrialTruth` per loading. A runner's trial loads the line once, so the truth's
trials are the run's trials in order. `truth()` returns the ground truth as a typed record
(`rig.sim.truth.WorldTruth`, built by `world_truth.py`).

**Fast path.** `advance_to` spells out the common substep (no slip under way, nothing pending,
no fork pushing) instead of calling `_substep`, and skips still stretches when the devices are at
rest; `plain_substeps = True` sends every substep through `_substep` (tests/test_sim_fast_paths.py
holds the two histories equal).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from rig.sim.kinds import ArticleSetup, SlipKind
from rig.sim.physics.forks import ForkFixture, ShaftDrivenForks
from rig.sim.physics.link import ChainLink
from rig.sim.physics.link_presets import STREAM_BEND, SimPreset, stream_rng
from rig.sim.physics.slips import ActiveSlip, SlipBehaviour, SlipRecord, Sudden, behaviour_for
from rig.sim.physics.tension_history import TensionHistory
from rig.sim.physics.trial_draws import TrialDraws
from rig.sim.physics.winch_line import WinchLine
from rig.sim.physics.world_truth import world_truth
from rig.sim.truth import SlipPlan, SlipTruth, TrialTruth, WorldTruth
from rig.vocabulary import TrialKind

DEFAULT_SUBSTEP_NS = 1_000_000
DEFAULT_HISTORY_S = 2.0
BEND_UPDATE_NS = 50_000_000  # how often a pushing fork re-poses the link (each re-pose costs ~0.2 ms)
# A slipped joint re-sticks with fresh static friction once the line has been slack this long: as
# long as a careful person waits with the line slack before touching the rig (the twin's hand).
RESTICK_S = 0.3


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


class SimWorld:
    """The rig's physics in virtual time; see the module docstring."""

    def __init__(
        self,
        preset: SimPreset,
        winch: ShaftLike,
        *,
        forks: Sequence[tuple[int, ShaftLike]] = (),
        pinion_radius_m: float = 0.01,
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
        self.step_devices = step_devices
        # True when stepping the devices would move nothing until the load on them changes
        # (`ObjectServoBus.at_rest`); lets `advance_to` skip a still stretch in one go.
        self.devices_at_rest = devices_at_rest
        # True: every substep goes through `_substep` (the plain twin of the fast path in `advance_to`).
        self.plain_substeps = False
        self._substep_ns = int(substep_ns)
        self._now_ns = int(start_ns)
        self._draws = TrialDraws(preset, seed)
        self.run_clock_offset_ns = int(run_clock_offset_ns)

        self.link = ChainLink(
            preset.segment_lengths_m,
            preset.point_m,
            preset.direction_w,
            preset.joint_capacities_nm,
            torsion_weak_joint=preset.torsion_weak_joint,
            torsion_ratio=preset.torsion_ratio,
        )
        self.specimen = ChainLink(
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
        self.forks: ShaftDrivenForks | None = None
        if forks:
            fixture = ForkFixture(
                self.link,
                [component for component, _ in forks],
                pinion_radius_m=pinion_radius_m,
                contact_stiffness_n_per_m=preset.fork_contact_stiffness_n_per_m,
                kinetic_ratio=preset.kinetic_ratio,
            )
            self.forks = ShaftDrivenForks(fixture, dict(forks), update_ns=BEND_UPDATE_NS)
        self._hand_rng = stream_rng(seed, STREAM_BEND)  # a person's placement error, bending by hand

        self.trials: list[TrialTruth] = []
        self.slips: list[SlipRecord] = []
        # The link's true transforms at the onset of each of its slips not yet measured (slip index ->
        # (J, 4, 4)); the configuration source takes them out as it measures.
        self.link_before_slip: dict[int, np.ndarray] = {}
        self._slip: ActiveSlip | None = None  # the slip under way
        self._behaviour: SlipBehaviour = Sudden(SlipPlan(SlipKind.SUDDEN), preset.kinetic_ratio)
        self._clamp_take_up_m = 0.0  # what an other-joint slip let the line in by (this hook-up)
        self._hook_joint: int | None = None  # the specimen is this joint of the link (None: nominal)
        self._hook_distance_m: float | None = None  # the hook's distance on the specimen
        # The friction is fresh (the next taut line draws a trial), a slip happened since the last
        # draw (a slack line re-sticks it), and since when the line has been slack after that slip.
        self._fresh = True
        self._slipped = False
        self._slack_since_ns: int | None = None
        self._watching = True  # _fresh or _slipped: whether a substep must watch the line

        tension = self.line.tension_n(winch.present_position_rad, self.line_take_up_m())
        self.history = TensionHistory(int(history_s * 1e9 / self._substep_ns) + 16, self._now_ns, tension)
        # The load cells' signal: the tension at a time, or at a tick's batch of times (TensionHistory).
        self.tension_at: Callable[[int], float] = self.history.at
        self.tensions_at: Callable[[Sequence[int]], list[float]] = self.history.at_many
        winch.external_torque_nm = self.line.winch_torque_nm(tension)

    # --- state -------------------------------------------------------------------------------
    @property
    def substep_ns(self) -> int:
        """The integration substep [ns]."""
        return self._substep_ns

    @property
    def now_ns(self) -> int:
        """The time (monotonic ns) the world has been integrated to."""
        return self._now_ns

    @property
    def tension_n(self) -> float:
        """The most recently recorded line tension [N]."""
        return self.history.tensions_n[-1]

    @property
    def setup(self) -> ArticleSetup:
        """Which article the line is hooked to: the link or the specimen."""
        return ArticleSetup.LINK if self._article is self.link else ArticleSetup.SPECIMEN

    @property
    def hook_distance_m(self) -> float | None:
        """Where the hook hangs on the specimen (None: the line is on the link)."""
        return self._hook_distance_m if self._article is self.specimen else None

    @property
    def article(self) -> ChainLink:
        """The article the line is hooked to."""
        return self._article

    @property
    def slipping(self) -> bool:
        """True while a joint is sliding."""
        return self._slip is not None

    @property
    def bending(self) -> bool:
        """True while a fork is closed on the link (and holding it)."""
        return self.forks is not None and self.forks.pushing

    @property
    def slip_rate_rad_s(self) -> float:
        """How fast a slipping joint turns (the preset's)."""
        return self.preset.slip_rate_rad_s

    def taut_winch_angle_rad(self) -> float:
        """The winch angle at which the line becomes taut in the present configuration (tests, scripts)."""
        return self.line.slack_angle_rad + self.line_take_up_m() / self.line.drum_radius_m

    def line_take_up_m(self) -> float:
        """The line's take-up: the article's, plus a neighbouring joint's slip (joint estimation)."""
        return self._article.take_up_m + self._clamp_take_up_m

    def let_line_in(self, length_m: float) -> None:
        """A joint outside the article turned (an other-joint slip): the take-up grows by `length_m`."""
        self._clamp_take_up_m += length_m

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
        history = self.history
        times, tensions, keep = history.times_ns, history.tensions_n, 2 * history.keep
        behaviour = self._behaviour  # refreshed when a loading draws its trial within the advance
        if self.plain_substeps:
            while t_ns < now_ns:
                t_ns = min(t_ns + step_ns, now_ns)
                self._substep(t_ns)
            return
        last_theta = math.nan
        while t_ns < now_ns:
            t_ns = min(t_ns + step_ns, now_ns)
            forks = self.forks
            if self._slip is not None or behaviour.pending or (forks is not None and forks.pushing):
                self._substep(t_ns)
                continue
            # Fast path of `_substep` for its common case (no slip under way, nothing pending, the
            # fixture still): the same steps in the same order, calls spelled out.
            if step_devices is not None:
                step_devices(t_ns)
            article = self._article
            theta = winch.present_position_rad
            stretch = radius * (theta - slack) - (article.take_up_m + self._clamp_take_up_m)
            tension = stiffness * stretch if stretch > 0.0 else 0.0  # WinchLine.tension_n
            times.append(t_ns)  # TensionHistory.record, spelled out
            tensions.append(tension)
            if len(times) > keep:
                history.trim()
            if self._watching and self._watch_line(tension, t_ns):
                behaviour = self._behaviour
            still = False
            if tension > behaviour.other_load_n:
                tension = behaviour.slip_other_joint(self, theta, tension, t_ns)
            elif tension > article.slip_threshold_n:
                tension = self._start_slip(theta, tension, (t_ns - self._now_ns) * 1e-9, t_ns)
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
                    self.history.record(later_ns, tension)
                self._now_ns = now_ns
                if self._watching:
                    self._watch_line(tension, now_ns)
                return

    def _substep(self, t_ns: int) -> None:
        """One substep, every case (the plain twin of the fast path in `advance_to`)."""
        dt_s = (t_ns - self._now_ns) * 1e-9
        if self.step_devices is not None:
            self.step_devices(t_ns)
        forks = self.forks
        holding = False
        if forks is not None and forks.pushing:
            forks.follow(t_ns)
            holding = self._article is self.link
        article = self._article
        theta = self._winch.present_position_rad
        tension = self.line.tension_n(theta, article.take_up_m + self._clamp_take_up_m)
        self.history.record(t_ns, tension)
        if self._watching:
            self._watch_line(tension, t_ns)
        if not holding:
            slip, behaviour = self._slip, self._behaviour
            if slip is not None:
                tension = slip.step(self, theta, tension, dt_s, t_ns)
                if slip.done:
                    self._slip = None
            elif tension > behaviour.other_load_n:
                tension = behaviour.slip_other_joint(self, theta, tension, t_ns)
            elif tension > article.slip_threshold_n or (behaviour.pending and behaviour.due(tension, t_ns)):
                tension = self._start_slip(theta, tension, dt_s, t_ns)
        self._winch.external_torque_nm = -tension * self.line.drum_radius_m
        self._now_ns = t_ns

    def _start_slip(self, theta: float, tension: float, dt_s: float, t_ns: int) -> float:
        """A slip of the trial's kind starts now and takes its first substep; the tension after it."""
        slip = self._behaviour.start(self, tension, t_ns)
        tension = slip.step(self, theta, tension, dt_s, t_ns)
        self._slip = None if slip.done else slip
        return tension

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
        if self._article is self.link:
            self.link_before_slip[len(self.slips)] = self.link.transforms  # as it was before it turns
        onset = SlipTruth(
            trial_index=self.trials[-1].index if self.trials else None,
            setup=self.setup,
            joint=joint,
            onset_ns=t_ns,
            peak_tension_n=tension_n,
            threshold_n=threshold_n,
            kind=kind,
            moved_joint=self._moved_joint(joint) if moved_joint is None else moved_joint,
            onset_time_ns=t_ns + self.run_clock_offset_ns,
        )
        record = SlipRecord(onset)
        self.slips.append(record)
        self._slipped = self._watching = True
        self._slack_since_ns = None
        return record

    def _moved_joint(self, article_joint: int) -> int:
        """The link joint that a slip of `article_joint` of the present article moves."""
        if self._article is self.link:
            return article_joint
        trial = self.current_trial
        return 1 if trial is None or trial.specimen_joint is None else trial.specimen_joint

    def _end_slip(self) -> None:
        """Cut the slip under way short (a new trial, the link re-posed) and forget what is pending."""
        if self._slip is not None:
            self._slip.finish(self._now_ns, self.tension_n)
            self._slip = None
        self._behaviour.end()

    def _watch_line(self, tension: float, t_ns: int) -> bool:
        """A taut line with fresh friction draws its trial (True); a slack one re-sticks a slipped joint."""
        if tension > 0.0:
            self._slack_since_ns = None
            if self._fresh:
                self.draw_trial(t_ns)
                return True
            return False
        if self._slipped and self._slip is None:
            if self._slack_since_ns is None:
                self._slack_since_ns = t_ns
            elif t_ns - self._slack_since_ns >= RESTICK_S * 1e9:
                self._make_fresh()
        return False

    def _make_fresh(self) -> None:
        """The joints' static friction is fresh: the next loading draws its trial."""
        self._fresh = self._watching = True
        self._slipped = False
        self._slack_since_ns = None

    # --- what is done to the rig -------------------------------------------------------------
    def place_hook(self, distance_m: float, joint: int | None = None) -> None:
        """A person hooks the line to the specimen at `distance_m` and levels it (joint estimation).

        `joint` (1-based) makes the specimen that joint of the link (its true mean capacity); without
        it the specimen is the preset's nominal joint.
        """
        if not (math.isfinite(distance_m) and distance_m > 0):
            raise ValueError(f"the hook needs distance_m > 0; got {distance_m!r}")
        if joint is not None and not 1 <= joint <= self.preset.joint_count:
            raise ValueError(f"joint = {joint}; allowed: 1..{self.preset.joint_count} or None")
        self._end_slip()
        self._hook_joint, self._hook_distance_m = joint, float(distance_m)
        self._article = self.specimen
        self.specimen.set_joint_angles([0.0])
        self.specimen.set_point((0.0, 0.0, float(distance_m)))
        self._clamp_take_up_m = 0.0
        self._make_fresh()

    def hook_link(self) -> None:
        """The line goes to the link's load point (link validation): what bending the link also does."""
        self._end_slip()
        self._article = self.link
        self._clamp_take_up_m = 0.0
        self._make_fresh()

    def engage_fork(self, component: int) -> None:
        """Close fork `component` on the link (the line on it); it pushes the link as its bender moves."""
        if self.forks is None:
            raise RuntimeError(f"this world has no fork on component {component}")
        self.hook_link()
        self.forks.close(component, self._now_ns)

    def straighten(self) -> None:
        """A reset: the forks open and a straight guide bar puts the link exactly straight."""
        if self.forks is not None:
            self.forks.open()
        self.set_configuration([0.0] * self.preset.joint_count)

    def bend_by_hand(self, joint_angles_rad: Sequence[float]) -> None:
        """A person bends the link: the requested angles plus their placement error N(0, σ_bend) each."""
        target = np.asarray(joint_angles_rad, dtype=float)
        sigma = self.preset.sigma_bend_rad
        error = self._hand_rng.normal(0.0, sigma, target.shape) if sigma > 0 else np.zeros(target.shape)
        self.set_configuration(tuple(float(a) for a in target + error))

    def set_configuration(self, joint_angles_rad: Sequence[float]) -> None:
        """Place the link in a planar configuration at once, exactly (a person, or a test); the line on it."""
        self.hook_link()
        self.link.set_joint_angles(joint_angles_rad)

    # --- trials ------------------------------------------------------------------------------
    def draw_trial(self, t_ns: int | None = None) -> TrialTruth:
        """The loading starting now draws its capacities and slip kind (the world does this itself).

        The world calls it when the line becomes taut with fresh friction; a test may call it to see
        a draw without loading the line.
        """
        self._end_slip()
        self.link_before_slip.clear()
        self._fresh = self._slipped = self._watching = False
        joint_estimation = self._article is self.specimen
        joint = self._hook_joint if joint_estimation else None
        draw = self._draws.draw(self._article, joint_estimation=joint_estimation, specimen_joint=joint)
        self._behaviour = behaviour_for(draw.plan, self.preset.kinetic_ratio)
        trial = TrialTruth(
            index=len(self.trials) + 1,
            kind=TrialKind.JOINT_ESTIMATION if joint_estimation else TrialKind.LINK_VALIDATION,
            distance_m=self._hook_distance_m if joint_estimation else None,
            specimen_joint=joint,
            start_ns=self._now_ns if t_ns is None else t_ns,
            capacities_nm=self._article.capacities_nm,
            capacity_factors=tuple(float(f) for f in draw.capacity.factors),
            slip_force_n=self._article.slip_threshold_n,
            slip_mass_kg=self._article.slip_threshold_n / self.preset.g,
            first_slip_joint=self._article.governing_joint,
            slip=draw.plan,
            capacity_relative_sds=tuple(float(x) for x in draw.capacity.relative_sds),
        )
        self.trials.append(trial)
        return trial

    def truth(self) -> WorldTruth:
        """Ground truth: what the world was made with, every trial's draws and every slip so far."""
        return world_truth(self)
