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
tension linearly over the last `history_s` seconds (the load-cell emulator's signal source).

**Slip kinds.** Each trial draws its kind and its capacities (`trial_draws.py`, each on its own
random stream of the seed); the kind becomes the trial's `SlipBehaviour` (`slips.py`: sudden, small
drop, creep, stick-slip train, other joint first, no slip), which opens the slip at the slip load and
steps it until the joint sticks again. Every slip event is a `SlipRecord` with its kind, its onset on
the run clock and its load.

Trials: `begin_trial(kind, distance_m)` draws the capacities of this trial and, for joint
estimation, sets up the **single-joint specimen**: one joint placed horizontally (its axis z along
the base z, the line pulling across it along the preset's direction without its z part), the hook
at distance l, so the lever arm is l. The specimen is re-levelled (straight) at the start of every
such trial. Link-validation trials use the link in whatever configuration the forks (or
`set_configuration`) left it. `truth()` returns the ground truth as a typed record
(`rig.hw.truth.WorldTruth`).

**Fast path.** `advance_to` spells out the common substep (no slip under way, nothing pending,
no fork pushing) instead of calling `_substep`, and skips still stretches when the devices are at
rest; `plain_substeps = True` sends every substep through `_substep` (tests/test_sim_fast_paths.py
holds the two histories equal).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np

from model.joint import mu_delta0_pa_from_capacity, resolve_constant
from rig.sim.kinds import ArticleSetup, SlipKind
from rig.sim.physics.article import ChainArticle
from rig.sim.physics.article_presets import STREAM_BEND, SimPreset, stream_rng
from rig.sim.physics.forks import ForkFixture
from rig.sim.physics.slips import ActiveSlip, SlipBehaviour, SlipRecord, Sudden, behaviour_for
from rig.sim.physics.trial_draws import TrialDraws
from rig.sim.physics.winch_line import WinchLine
from rig.sim.truth import (
    CapacityTruth,
    GeometryTruth,
    LineTruth,
    NoiseTruth,
    ScatterTruth,
    SlipPlan,
    SlipTruth,
    TrialTruth,
    WorldTruth,
)
from rig.vocabulary import TrialKind

DEFAULT_SUBSTEP_NS = 1_000_000
DEFAULT_HISTORY_S = 2.0
BEND_UPDATE_NS = 50_000_000  # how often a pushing fork re-poses the link (each re-pose costs ~0.2 ms)


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
        self._fork_shafts = {component: shaft for component, shaft in forks}
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
        self.fixture: ForkFixture | None = None
        if self._fork_shafts:
            self.fixture = ForkFixture(
                self.link,
                list(self._fork_shafts),
                pinion_radius_m=pinion_radius_m,
                contact_stiffness_n_per_m=preset.fork_contact_stiffness_n_per_m,
                kinetic_ratio=preset.kinetic_ratio,
            )
        self._hand_rng = stream_rng(seed, STREAM_BEND)  # a person's placement error, bending by hand
        self._last_bend_update_ns = self._now_ns

        self.trials: list[TrialTruth] = []
        self.slips: list[SlipRecord] = []
        # The link's true transforms at the onset of each of its slips not yet measured (slip index ->
        # (J, 4, 4)); the configuration source takes them out as it measures.
        self.link_before_slip: dict[int, np.ndarray] = {}
        self._slip: ActiveSlip | None = None  # the slip under way
        self._behaviour: SlipBehaviour = Sudden(SlipPlan(SlipKind.SUDDEN), preset.kinetic_ratio)
        self._clamp_take_up_m = 0.0  # what an other-joint slip let the line in by (this trial)

        self._history_len = int(history_s * 1e9 / self._substep_ns) + 16
        tension = self.line.tension_n(winch.present_position_rad, self.line_take_up_m())
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
    def setup(self) -> ArticleSetup:
        """Which article the line is hooked to: the link or the specimen."""
        return ArticleSetup.LINK if self._article is self.link else ArticleSetup.SPECIMEN

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
        """True while a fork is closed on the link (and holding it)."""
        return self.fixture is not None and self.fixture.active is not None

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
        times, tensions, keep = self._times_ns, self._tensions_n, 2 * self._history_len
        behaviour = self._behaviour  # no trial begins within an advance
        if self.plain_substeps:
            while t_ns < now_ns:
                t_ns = min(t_ns + step_ns, now_ns)
                self._substep(t_ns)
            return
        last_theta = math.nan
        while t_ns < now_ns:
            t_ns = min(t_ns + step_ns, now_ns)
            fixture = self.fixture
            if (
                self._slip is not None
                or behaviour.pending
                or (fixture is not None and fixture.active is not None)
            ):
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
            times.append(t_ns)  # _record, spelled out
            tensions.append(tension)
            if len(times) > keep:
                self._trim_history()
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
        """One substep, every case (the plain twin of the fast path in `advance_to`)."""
        dt_s = (t_ns - self._now_ns) * 1e-9
        if self.step_devices is not None:
            self.step_devices(t_ns)
        fixture = self.fixture
        holding = False
        if fixture is not None and fixture.active is not None:
            self._follow_fixture(fixture, t_ns)
            holding = self._article is self.link
        article = self._article
        theta = self._winch.present_position_rad
        tension = self.line.tension_n(theta, article.take_up_m + self._clamp_take_up_m)
        self._record(t_ns, tension)
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
        return record

    def _moved_joint(self, article_joint: int) -> int:
        """The link joint that a slip of `article_joint` of the present article moves."""
        if self._article is self.link:
            return article_joint
        trial = self.current_trial
        return 1 if trial is None or trial.specimen_joint is None else trial.specimen_joint

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

    def _end_slip(self) -> None:
        """Cut the slip under way short (a new trial, the link re-posed) and forget what is pending."""
        if self._slip is not None:
            self._slip.finish(self._now_ns, self.tension_n)
            self._slip = None
        self._behaviour.end()

    # --- bending -----------------------------------------------------------------------------
    def _follow_fixture(self, fixture: ForkFixture, t_ns: int) -> None:
        active = fixture.active
        if active is None or t_ns - self._last_bend_update_ns < BEND_UPDATE_NS:
            return
        self._last_bend_update_ns = t_ns
        fixture.update(self._fork_shafts[active].present_position_rad)

    def engage_fork(self, component: int) -> None:
        """Close fork `component` on the link; it pushes the link as its bender moves (forks.py)."""
        if self.fixture is None or component not in self._fork_shafts:
            raise RuntimeError(f"this world has no fork on component {component}")
        if self._article is self.link:
            self._end_slip()
        self.fixture.engage(component, self._fork_shafts[component].present_position_rad)
        self._last_bend_update_ns = self._now_ns

    def settle_fork(self) -> None:
        """The moving fork has stopped: let the link follow it to its final angle, then hold."""
        fixture = self.fixture
        if fixture is not None and fixture.active is not None:
            fixture.update(self._fork_shafts[fixture.active].present_position_rad)
            fixture.active = None

    def open_forks(self) -> None:
        """Open every fork: the link is free (the trial may load it)."""
        if self.fixture is not None:
            self.settle_fork()
            self.fixture.open_all()

    def straighten(self) -> None:
        """A reset: the forks open and a straight guide bar puts the link exactly straight."""
        self.open_forks()
        self.set_configuration([0.0] * self.preset.joint_count)

    def bend_by_hand(self, joint_angles_rad: Sequence[float]) -> None:
        """A person bends the link: the requested angles plus their placement error N(0, σ_bend) each."""
        target = np.asarray(joint_angles_rad, dtype=float)
        sigma = self.preset.sigma_bend_rad
        error = self._hand_rng.normal(0.0, sigma, target.shape) if sigma > 0 else np.zeros(target.shape)
        self.set_configuration(tuple(float(a) for a in target + error))

    def set_configuration(self, joint_angles_rad: Sequence[float]) -> None:
        """Place the link in a planar configuration at once, exactly (an operator, or a test)."""
        if self._article is self.link:
            self._end_slip()
        self.link.set_joint_angles(joint_angles_rad)

    # --- trials ------------------------------------------------------------------------------
    def begin_trial(
        self, kind: TrialKind | str, distance_m: float | None = None, joint: int | None = None
    ) -> TrialTruth:
        """Start a trial: draw its capacities and slip kind; for joint estimation hook the specimen.

        For joint estimation, `joint` (1-based) makes the specimen that joint of the link (its true
        mean capacity); without it the specimen is the preset's nominal joint, at `distance_m`.
        """
        kind = TrialKind(kind)
        self._end_slip()
        self.link_before_slip.clear()
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
        self._clamp_take_up_m = 0.0
        draw = self._draws.capacity_factors(nominal, self._article)
        plan = self._draws.slip_plan(kind is TrialKind.JOINT_ESTIMATION, joint)
        capacities = nominal * draw.factors
        if plan.kind == SlipKind.NO_SLIP:
            capacities = capacities * preset.slip_mix.no_slip_capacity_factor
        self._article.set_capacities(capacities)
        threshold = self._article.slip_threshold_n
        if plan.kind == SlipKind.OTHER_JOINT:
            assert plan.other_load_n is not None
            # The fraction drawn becomes a load (inf if the specimen cannot slip).
            plan = replace(plan, other_load_n=plan.other_load_n * threshold)
        self._behaviour = behaviour_for(plan, preset.kinetic_ratio)
        trial = TrialTruth(
            index=len(self.trials) + 1,
            kind=kind,
            distance_m=None if distance_m is None else float(distance_m),
            specimen_joint=joint,
            start_ns=self._now_ns,
            capacities_nm=self._article.capacities_nm,
            capacity_factors=tuple(float(f) for f in draw.factors),
            slip_force_n=threshold,
            slip_mass_kg=threshold / preset.g,
            first_slip_joint=self._article.governing_joint,
            slip=plan,
            capacity_relative_sds=tuple(float(x) for x in draw.relative_sds),
        )
        self.trials.append(trial)
        return trial

    # --- ground truth ------------------------------------------------------------------------
    def truth(self) -> WorldTruth:
        """Ground truth: what the world was made with, every trial's draws and every slip so far."""
        p = self.preset
        constant = resolve_constant(p.constant)

        def capacity(capacity_nm: float) -> CapacityTruth:
            mu_delta0_pa = float(mu_delta0_pa_from_capacity(capacity_nm, p.joint_radius_m, constant))
            return CapacityTruth(capacity_nm, capacity_nm / p.g, mu_delta0_pa)

        return WorldTruth(
            preset=p.name,
            seed=self.seed,
            article_seed=p.seed,
            g=p.g,
            constant_name=constant.name,
            constant_c=constant.value,
            joint_radius_m=p.joint_radius_m,
            joints=tuple(capacity(c) for c in p.joint_capacities_nm),
            specimen=capacity(p.specimen_capacity_nm),
            noise=NoiseTruth(
                per_trial_capacity_sd=p.per_trial_capacity_sd,
                loadcell_noise_n=p.loadcell_noise_n,
                sigma_bend_rad=p.sigma_bend_rad,
                sigma_meas_rad=p.sigma_meas_rad,
                slipped_joint_report_probability=p.slipped_joint_report_probability,
            ),
            kinetic_ratio=p.kinetic_ratio,
            scatter=ScatterTruth(p.scatter_shape, p.scatter_a_kg, p.per_trial_capacity_sd),
            slip_mix=p.slip_mix,
            loadcell_artefacts=p.loadcell_artefacts,
            run_clock_offset_ns=self.run_clock_offset_ns,
            slip_rate_rad_s=p.slip_rate_rad_s,
            torsion_weak_joint=p.torsion_weak_joint,
            torsion_ratio=p.torsion_ratio,
            geometry=GeometryTruth(
                segment_lengths_m=tuple(p.segment_lengths_m),
                point_m=tuple(p.point_m),
                direction_w=tuple(p.unit_direction_w),
                joint_estimation_distances_m=tuple(p.joint_estimation_distances_m),
            ),
            line=LineTruth(
                drum_radius_m=p.drum_radius_m,
                line_stiffness_n_per_m=p.line_stiffness_n_per_m,
                spring_stiffness_n_per_m=p.spring_stiffness_n_per_m,
                effective_stiffness_n_per_m=self.line.stiffness_n_per_m,
                winch_slack_rad=p.winch_slack_rad,
            ),
            substep_ns=self._substep_ns,
            trials=tuple(self.trials),
            slips=tuple(s.truth() for s in self.slips),
        )
