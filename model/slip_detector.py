"""Slip detection on the line-tension signal: a pure step function over (time, force) samples.

The runner steps it live in the acquisition loop (up to 1 kHz) and `rig replay` steps it again over
the logged samples; both call the same `detector_step`, so both find the same events.

Detector (docs/model.md §7):
1. **Arm** when the force reaches `arm_threshold_n`: below it the signal is handling noise.
2. While armed, **track the running peak** (a plateau's peak time is its last sample at the peak),
   and a spike-robust peak: the running peak of min(f[k−1], f[k]).
3. On every sample, **estimate the ramp and the noise** from the increments f[k] − f[k−1]: a robust
   running mean of the increment (the ramp) and of |increment − ramp| (σ·2/√π for white noise).
4. **Fire** on any enabled trigger ("high" is max(f[k−1], f[k]), so one spike never fires):
   * `drop`: high is `drop_fraction` of the spike-robust peak (decaying at `drop_leak_n_per_s`)
     and `min_drop_n` below it;
   * `slope`: the least-squares slope over the last `slope_window_s` is <= −`slope_n_per_s`;
   * `cusum`: a one-sided CUSUM of force decrements, `g ← max(g + (f[k−1] − f[k]) − drift·Δt, 0)`,
     exceeds `cusum_threshold_n`; its onset is the last sample at which g was 0;
   * `noise`: high is `noise_k`·σ below the spike-robust peak decaying at `peak_leak_n_per_s`;
   * `creep`: a CUSUM of the fall relative to the ramp trend and the fall of high below the
     spike-robust peak both reach `creep_k`·σ (the tension sags while the winch reels).
   slope and cusum fire only once the force is at least `min_drop_n` below the peak.
5. **Latch** after firing: no trigger fires until the force falls below `rearm_below_n`, then the
   detector waits to arm again. So one slip fires once, and a slip that releases the line below the
   re-arm level and re-tensions fires again. The default re-arm level is half the arm threshold:
   re-arming right at the arm threshold would let load-cell noise around it arm the detector on the
   unloading ramp after a slip, and that (real) decline would fire a second event.
6. **Count further drops while latched** (stick-slip): a fall of `train_k`·σ below the highest
   spike-robust level of the last `train_window_s` (at least `TRAIN_MIN_SAMPLES` samples), after
   those samples held steady or rose (a sag that goes on, as creep does, falls as much before as
   in its last samples: not a drop).
   The latch starts the count at 0; each counted drop restarts the window. `further_drops` steps
   the detector over the hold after an event and returns the count: the runner and replay both
   classify a stick-slip train with it. The count changes no event.

Event times: `onset_time_ns` is the earliest onset the firing triggers point to (the peak time for
drop, slope and noise, the CUSUM onset for cusum, the trend CUSUM's onset but not before the peak
for creep); `detection_time_ns` is the sample that fired. `kind` is 'creep' for a slow sag, else
'drop'.

Cost per sample: a few float comparisons and one frozen-state construction. The slope trigger,
when enabled, keeps a ring of the samples inside its window (a tuple) and computes the centred
least-squares slope over it, O(window samples) per sample (about 20 at 1 kHz and 20 ms); running
sums would make that O(1) but, with nanosecond times, lose most of their digits to cancellation,
and this detector must give replay exactly what it gave live.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from enum import StrEnum
from typing import Any, NamedTuple

from model.field_spec import Declared, FieldSpec, declared_fields, number

_NONE_WORDS = frozenset({"none", "null", "off", "disabled", ""})


# Fields that `to_mapping` names only when set (None is their default: a detector that does not use
# them logs the mapping it did before they existed).
_LOGGED_WHEN_SET = frozenset({"drop_ramp_s"})


@dataclass(frozen=True)
class DetectorParams:
    """Settings of the slip detector (all forces in N, times in s). See the module docstring.

    Attributes:
        arm_threshold_n: the detector arms when the force reaches this, (0, 1e6] N.
        drop_fraction: fire when the force has fallen by this fraction of the peak, (0, 1); None: off.
        min_drop_n: no trigger fires before the force is this far below the peak, [0, 1e6] N.
        slope_n_per_s: fire when the slope over the window is <= −this, (0, 1e9] N/s; None: off.
        slope_window_s: the window of the slope fit, (0, 10] s.
        cusum_threshold_n: fire when the CUSUM of decrements exceeds this, (0, 1e6] N; None: off.
        cusum_drift_n_per_s: the CUSUM's drift allowance, subtracted at this rate (a fall slower
            than this is ignored), [0, 1e9] N/s.
        rearm_below_n: after firing, wait until the force is below this before arming again,
            (0, 1e6] N; None: half the arm threshold (a hysteresis band against noise).
        noise_k: fire when the force is this many noise σ below the leaky peak, (0, 1e3]; None: off.
        noise_floor_n: the least noise σ the noise-scaled triggers assume, (0, 1e6] N.
        noise_window_s: time constant of the running noise estimate, (0, 100] s.
        trend_window_s: time constant of the running ramp-rate estimate, (0, 100] s.
        peak_leak_n_per_s: the noise trigger's peak decays at this rate (drift is not a drop),
            [0, 1e9] N/s.
        creep_k: fire when the CUSUM of the deviation from the ramp and the fall below the peak both
            exceed this many noise σ, (0, 1e3]; None: off.
        creep_drift_n_per_s: the CUSUM's allowance (slower sag relative to the ramp is ignored),
            [0, 1e9] N/s.
        creep_min_s: an event is of kind 'creep' if only the creep trigger fired, or if it was
            detected at least this long after its onset, [0, 100] s.
        spike_samples: 2: the percentage drop compares max(f[k−1], f[k]) with the peak of
            min(f[k−1], f[k]) (one spike never fires it); 1: single samples (before 2026-11-23).
        drop_leak_n_per_s: the percentage drop's spike-robust peak decays at this rate, so that a
            slow drift on a noisy cell is not a drop, [0, 1e9] N/s; 0: it never decays (as before
            the train rule).
        drop_ramp_s: the percentage drop's peak is carried on along the running ramp rate for up to
            this long after the peak (by at most half the drop), and the newer sample of the pair
            need only be half the drop below it, so that the line's re-tension between samples does
            not hide a drop at a low rate; the spike guard is ramp-aware: a single-sample peak
            whose rise is at most twice the rise before it is a peak, and when the older sample of
            the pair has already fallen (4 σ, or min_drop_n), the newer alone is the level,
            [0, 100] s; None: none of these (as before 2026-11-27; the default at 1000 samples/s
            and above, `rate_defaults` sets 3 sample periods below).
        train_k: after an event, a sudden fall of this many noise σ counts as a further drop of a
            stick-slip train (`further_drops`), (0, 1e3]; None: off (no train is counted). It
            changes no event, only how the runner classifies the trial.
        warmup_s: the running ramp and noise estimates average their first increments with equal
            weights for this long, and over at least `WARMUP_MIN_INCREMENTS` increments; the
            noise-scaled triggers wait for it, [0, 100] s; 0: the increments only (16 ms at
            1000/s, as before). A longer default was measured worse: a 16 ms warm-up at 2000/s
            (32 increments) takes in the ramp's start, its σ grows 10×, and a 3 % drop is missed.
        train_window_s: latched, a further drop is a fall below the highest level of this long
            before it, and at least `TRAIN_MIN_SAMPLES` samples, [0, 100] s.
    """

    arm_threshold_n: float = field(default=1.0, metadata=number(0.0, 1e6, lo_open=True, unit="N"))
    drop_fraction: float | None = field(
        default=0.15, metadata=number(0.0, 1.0, lo_open=True, hi_open=True, optional=True)
    )
    min_drop_n: float = field(default=0.2, metadata=number(0.0, 1e6, unit="N"))
    slope_n_per_s: float | None = field(
        default=None, metadata=number(0.0, 1e9, lo_open=True, unit="N/s", optional=True)
    )
    slope_window_s: float = field(default=0.02, metadata=number(0.0, 10.0, lo_open=True, unit="s"))
    cusum_threshold_n: float | None = field(
        default=None, metadata=number(0.0, 1e6, lo_open=True, unit="N", optional=True)
    )
    cusum_drift_n_per_s: float = field(default=50.0, metadata=number(0.0, 1e9, unit="N/s"))
    rearm_below_n: float | None = field(
        default=None,
        metadata=number(0.0, 1e6, lo_open=True, unit="N", optional=True, default_doc="none (= arm/2)"),
    )
    noise_k: float | None = field(default=10.0, metadata=number(0.0, 1e3, lo_open=True, optional=True))
    noise_floor_n: float = field(default=0.002, metadata=number(0.0, 1e6, lo_open=True, unit="N"))
    noise_window_s: float = field(default=0.5, metadata=number(0.0, 100.0, lo_open=True, unit="s"))
    trend_window_s: float = field(default=0.2, metadata=number(0.0, 100.0, lo_open=True, unit="s"))
    peak_leak_n_per_s: float = field(default=1.0, metadata=number(0.0, 1e9, unit="N/s"))
    creep_k: float | None = field(default=10.0, metadata=number(0.0, 1e3, lo_open=True, optional=True))
    creep_drift_n_per_s: float = field(default=0.2, metadata=number(0.0, 1e9, unit="N/s"))
    creep_min_s: float = field(default=0.05, metadata=number(0.0, 100.0, unit="s"))
    spike_samples: float = field(
        default=2.0,
        metadata=number(
            1.0, 2.0, allowed_doc="1 or 2 (1: the percentage drop on single samples, as before 2026-11-23)"
        ),
    )
    train_k: float | None = field(default=10.0, metadata=number(0.0, 1e3, lo_open=True, optional=True))
    drop_leak_n_per_s: float = field(default=1.0, metadata=number(0.0, 1e9, unit="N/s"))
    drop_ramp_s: float | None = field(
        default=None,
        metadata=number(0.0, 100.0, unit="s", optional=True, default_doc="none (3 samples below 1 kHz)"),
    )
    warmup_s: float = field(default=0.0, metadata=number(0.0, 100.0, unit="s"))
    train_window_s: float = field(default=0.008, metadata=number(0.0, 100.0, unit="s"))

    def __post_init__(self) -> None:
        """Validate every field (a direct construction is checked like `from_mapping`)."""
        for declared in _FIELDS:
            value = _checked(declared, getattr(self, declared.name), "detector")
            object.__setattr__(self, declared.name, value)
        if self.spike_samples not in (1.0, 2.0):
            raise ValueError(f"detector: spike_samples = {self.spike_samples!r}; allowed: 1 or 2")
        triggers = [self.drop_fraction, self.slope_n_per_s, self.cusum_threshold_n, self.noise_k]
        if all(value is None for value in [*triggers, self.creep_k]):
            raise ValueError(
                "detector: no trigger enabled; allowed: set at least one of drop_fraction, "
                "slope_n_per_s, cusum_threshold_n, noise_k, creep_k"
            )

    @property
    def rearm_level_n(self) -> float:
        """The force below which a latched detector waits to arm again [N]."""
        return 0.5 * self.arm_threshold_n if self.rearm_below_n is None else self.rearm_below_n

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any], source: str = "detector") -> DetectorParams:
        """Build from a mapping (a protocol section, logged metadata, parsed `key=value` flags).

        Missing keys keep their defaults. Values may be numbers or strings ('0.2', 'none').
        Raises ValueError naming `source`, the field and the allowed range.
        """
        if not isinstance(mapping, Mapping):
            raise ValueError(f"{source}: expected a mapping of detector fields, got {type(mapping).__name__}")
        values: dict[str, Any] = {}
        for key, raw in mapping.items():
            name = str(key)
            declared = _BY_NAME.get(name)
            if declared is None:
                raise ValueError(
                    f"{source}: unknown field {name!r}{_suggestion(name)}; allowed: {_field_list()}"
                )
            values[name] = _checked(declared, raw, source)
        try:
            return cls(**values)
        except ValueError as exc:
            message = str(exc)
            raise ValueError(f"{source}: {message.removeprefix('detector: ')}") from None

    def with_overrides(self, assignments: Iterable[str], source: str = "--detector") -> DetectorParams:
        """These parameters with `key=value` strings applied (e.g. `drop_fraction=0.2`)."""
        mapping: dict[str, Any] = dict(self.to_mapping())
        for assignment in assignments:
            key, sep, value = assignment.partition("=")
            if not sep:
                raise ValueError(f"{source}: {assignment!r}: allowed: key=value, e.g. drop_fraction=0.2")
            mapping[key.strip()] = value.strip()
        return DetectorParams.from_mapping(mapping, source=source)

    def to_mapping(self) -> dict[str, float | None]:
        """Every field by name (None for disabled triggers): log it, re-apply it with `from_mapping`.

        The fields of `_LOGGED_WHEN_SET` are left out while None (their default): a detector that
        does not use them logs, and replays, the very mapping it did before they existed.
        """
        return {
            f.name: getattr(self, f.name)
            for f in fields(self)
            if f.name not in _LOGGED_WHEN_SET or getattr(self, f.name) is not None
        }


# The rate the defaults above were tuned at (the simulated cell's, 1000 samples/s), and the fields
# whose default follows the load cell's rate below it (`rate_defaults`).
TUNED_RATE_HZ = 1000.0
RATE_DEPENDENT_FIELDS = (
    "peak_leak_n_per_s", "drop_leak_n_per_s", "creep_min_s", "noise_window_s", "drop_ramp_s",
)  # fmt: skip
# At any rate: a sudden drop is seen on the 2nd sample after its onset, and the onset the detector
# gives is the peak sample, which on a stepped ramp's plateau (10/s) can be 4-5 samples before the slip; so
# an event detected this many sample periods after its onset or later is a creep (`creep_min_s`); ...
CREEP_MIN_SAMPLES = 8
# ... the noise σ is averaged over at least this many samples (`noise_window_s`); below the tuned
# rate the percentage drop's peak is carried along the ramp for this many periods (`drop_ramp_s`).
NOISE_WINDOW_SAMPLES = 100
DROP_RAMP_SAMPLES = 3


def rate_defaults(rate_hz: float) -> dict[str, float | None]:
    """The defaults of `RATE_DEPENDENT_FIELDS` for a load cell streaming `rate_hz` samples/s.

    At `TUNED_RATE_HZ` and above, the class defaults. Below it: the leaks of the peaks scale with
    the rate (the same fall per sample: over the 2 samples a drop takes to be seen, a fixed N/s leak
    would eat a 3 % drop at 10/s); `creep_min_s` is at least `CREEP_MIN_SAMPLES` periods (a slide
    shorter than that is called a drop: the limit of what the rate resolves); the noise window
    spans at least `NOISE_WINDOW_SAMPLES` samples (a σ from a few samples makes the 10σ triggers
    fire on noise); the percentage drop's peak is carried along the ramp for `DROP_RAMP_SAMPLES`
    periods (at 10/s the line re-tensions by up to 1 % of the load between two samples).
    """
    if not math.isfinite(rate_hz) or rate_hz <= 0.0:
        raise ValueError(f"rate_hz = {rate_hz!r}; allowed: a positive number of samples per second")
    base = DetectorParams()
    share = min(1.0, rate_hz / TUNED_RATE_HZ)
    return {
        "peak_leak_n_per_s": base.peak_leak_n_per_s * share,
        "drop_leak_n_per_s": base.drop_leak_n_per_s * share,
        "creep_min_s": max(base.creep_min_s, CREEP_MIN_SAMPLES / rate_hz),
        "noise_window_s": max(base.noise_window_s, NOISE_WINDOW_SAMPLES / rate_hz),
        "drop_ramp_s": None if rate_hz >= TUNED_RATE_HZ else DROP_RAMP_SAMPLES / rate_hz,
    }


def params_for_rate(params: DetectorParams, given: Iterable[str], rate_hz: float) -> DetectorParams:
    """`params` with each rate-dependent field not in `given` at its default for `rate_hz`.

    `given`: the fields the protocol set. Unchanged at `TUNED_RATE_HZ` and above.
    """
    chosen = set(given)
    updates = {name: value for name, value in rate_defaults(rate_hz).items() if name not in chosen}
    return DetectorParams.from_mapping({**params.to_mapping(), **updates}) if updates else params


# The fields and their bounds, as declared above (`model.field_spec`).
_FIELDS = declared_fields(DetectorParams)
_BY_NAME = {declared.name: declared for declared in _FIELDS}


def _field_list() -> str:
    return ", ".join(_BY_NAME)


def _suggestion(name: str) -> str:
    close = difflib.get_close_matches(name, list(_BY_NAME), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _allowed(spec: FieldSpec) -> str:
    text = f"a number in {spec.bounds.interval()}"
    return text + " or none (disabled)" if spec.optional else text


def _checked(declared: Declared, raw: Any, source: str) -> float | None:
    """`raw` as a validated float (or None for a disabled optional field); ValueError otherwise."""
    name, spec = declared.name, declared.spec
    if raw is None or (isinstance(raw, str) and raw.strip().lower() in _NONE_WORDS):
        if spec.optional:
            return None
        raise ValueError(f"{source}: {name} is required; allowed: {_allowed(spec)}")
    if isinstance(raw, bool):
        raise ValueError(f"{source}: {name} = {raw!r}; allowed: {_allowed(spec)}")
    try:
        value = float(raw)
    except (TypeError, ValueError):
        raise ValueError(f"{source}: {name} = {raw!r} is not a number; allowed: {_allowed(spec)}") from None
    if not spec.bounds.accepts(value):
        raise ValueError(f"{source}: {name} = {raw!r}; allowed: {_allowed(spec)}")
    return value


class SlipEventKind(StrEnum):
    """What a detected slip looked like: a sudden drop, or a slow sag (creep)."""

    DROP = "drop"
    CREEP = "creep"


class DetectorPhase(StrEnum):
    """Where the detector is in its arm / fire / re-arm cycle."""

    IDLE = "idle"  # below the arm threshold, waiting
    ARMED = "armed"  # tracking the peak, triggers live
    LATCHED = "latched"  # fired; waiting for the force to fall below the re-arm level


class DetectorState(NamedTuple):
    """Everything the detector remembers between samples (immutable; each step returns a new one).

    A NamedTuple rather than a frozen dataclass: one is built per load-cell sample (1 kHz), and a
    tuple is built in about a third of the time.
    """

    phase: DetectorPhase = DetectorPhase.IDLE
    last_time_ns: int | None = None
    peak_force_n: float = 0.0
    peak_time_ns: int = 0
    previous_force_n: float = 0.0
    cusum_n: float = 0.0
    cusum_onset_ns: int = 0
    window_times_ns: tuple[int, ...] = ()
    window_forces_n: tuple[float, ...] = ()
    increments: int = 0  # sample-to-sample increments seen so far (counted during the warm-up)
    rate_n: float = 0.0  # running ramp increment per sample [N]
    scale_n: float = 0.0  # running mean |increment − ramp increment| [N]
    robust_peak_n: float = 0.0  # peak of min(f[k−1], f[k]): single-sample spikes do not set it
    leaky_peak_n: float = 0.0  # the same, decaying at peak_leak_n_per_s
    trend_cusum_n: float = 0.0  # CUSUM of the fall relative to the ramp trend
    trend_onset_ns: int = 0  # the last sample at which trend_cusum_n was zero
    armed_at_n: float = 0.0  # min(f[k−1], f[k]) when the detector armed
    train_levels_n: tuple[float, ...] = ()  # latched: min(f[k−1], f[k]) of the last samples
    train_drops: int = 0  # latched: further drops counted since the latch
    drop_peak_n: float = 0.0  # the percentage drop's peak: robust_peak_n decaying at drop_leak_n_per_s
    # Kept only with drop_ramp_s set (which sends every sample to the plain step): f[k−2] and
    # f[k−2] − f[k−3], for the ramp-aware spike guard of the percentage drop.
    older_force_n: float = 0.0
    older_rise_n: float = 0.0
    first_time_ns: int = 0  # the first sample's time (the warm-up's start)
    warmed: bool = False  # the warm-up is over (`warmup_s` and `WARMUP_MIN_INCREMENTS`)


@dataclass(frozen=True, slots=True)
class SlipEvent:
    """One detected slip.

    Attributes:
        onset_time_ns: when the slip began (the peak, or the CUSUM onset) [ns, the samples' clock].
        detection_time_ns: the sample that fired [ns].
        peak_time_ns: the time of the running peak [ns].
        peak_force_n: the peak tension before the drop [N]: the slip load.
        force_after_n: the force at detection [N].
        drop_fraction: (peak − force_after) / peak at detection.
        trigger: the triggers that fired on that sample, joined by '+'
            ('drop', 'slope', 'cusum', 'noise', 'creep').
        kind: 'creep' if only the creep trigger fired or the detection came at least `creep_min_s`
            after the onset; 'drop' otherwise (sudden).
    """

    onset_time_ns: int
    detection_time_ns: int
    peak_time_ns: int
    peak_force_n: float
    force_after_n: float
    drop_fraction: float
    trigger: str
    kind: SlipEventKind = SlipEventKind.DROP


# Increments averaged with equal weights before the running estimates switch to their time
# constants: at least this many (a σ from fewer makes the 10σ triggers fire on noise), and at
# least `warmup_s` (default 0: this many at every rate; 16 ms at 1000/s).
WARMUP_MIN_INCREMENTS = 16
# Residuals beyond this many mean |residuals| are clipped in the running estimates (a slip or a
# spike must not inflate the noise estimate or drag the ramp rate).
_CLIP = 4.0
# Latched: a further drop is a fall of the level below the highest of the spike-robust levels of
# `train_window_s` (8 ms) and at least this many samples (the steadiness test below reads six of
# them); the window also makes the count wait that long after the latch (the first drop's tail).
TRAIN_MIN_SAMPLES = 8
# ... and the samples before it must have held or risen: the mean of the window's first three levels
# is at most this share of the fall (or of the threshold) above the mean of the three before the
# newest. A steady sag falls as much across the window as in its last samples, so it never counts.
_TRAIN_STEADY = 0.25
_TRAIN_STEADY_FLOOR = 0.15
# With drop_ramp_s set: an older sample of the pair this many noise σ below the one before it has
# begun to fall (the difference of two samples of pure noise, σ·√2, exceeds 4σ once in about 400).
_FALLING_SIGMA = 4.0
# E|x| / σ for x ~ N(0, 2σ²), the difference of two independent noise samples: 2/√π.
_MEAN_ABS_DIFF_PER_SIGMA = 2.0 / math.sqrt(math.pi)


class QuietUse(StrEnum):
    """How the fast path `_quiet_stretch` treats a `DetectorParams` field."""

    MIRRORED = "mirrored"  # read on every quiet sample, as `_estimates` and `detector_step` read it
    GATE = "gate"  # anything but None sends every sample to the plain `detector_step`
    PLAIN_ONLY = "plain only"  # read only where the fast path stops (arming, firing, the latch)


# Every field of `DetectorParams` and how the fast path handles it. A new field fails
# tests/test_slip_detector_fast_path.py until it is entered here (and, if mirrored, handled).
QUIET_STRETCH_FIELDS: dict[str, QuietUse] = {
    "arm_threshold_n": QuietUse.MIRRORED,
    "drop_fraction": QuietUse.MIRRORED,
    "min_drop_n": QuietUse.MIRRORED,
    "slope_n_per_s": QuietUse.GATE,  # the slope window is kept per sample: no fast path
    "slope_window_s": QuietUse.PLAIN_ONLY,  # read only with the slope trigger on
    "cusum_threshold_n": QuietUse.MIRRORED,
    "cusum_drift_n_per_s": QuietUse.MIRRORED,
    "rearm_below_n": QuietUse.PLAIN_ONLY,  # latched
    "noise_k": QuietUse.MIRRORED,
    "noise_floor_n": QuietUse.MIRRORED,
    "noise_window_s": QuietUse.MIRRORED,
    "trend_window_s": QuietUse.MIRRORED,
    "peak_leak_n_per_s": QuietUse.MIRRORED,
    "creep_k": QuietUse.MIRRORED,
    "creep_drift_n_per_s": QuietUse.MIRRORED,
    "creep_min_s": QuietUse.PLAIN_ONLY,  # the kind of an event that fired
    "spike_samples": QuietUse.MIRRORED,
    "train_k": QuietUse.PLAIN_ONLY,  # latched
    "drop_leak_n_per_s": QuietUse.MIRRORED,
    "drop_ramp_s": QuietUse.GATE,  # set below 1 kHz only: the plain step, sample by sample
    "warmup_s": QuietUse.PLAIN_ONLY,  # the fast path starts after the warm-up
    "train_window_s": QuietUse.PLAIN_ONLY,  # latched
}
_QUIET_GATES = tuple(name for name, use in QUIET_STRETCH_FIELDS.items() if use is QuietUse.GATE)


def detector_init(params: DetectorParams) -> DetectorState:
    """The state before the first sample (idle, nothing seen)."""
    if not isinstance(params, DetectorParams):
        raise TypeError(f"params must be DetectorParams, got {type(params).__name__}")
    return DetectorState()


def _window_slope_n_per_s(times_ns: Sequence[int], forces_n: Sequence[float]) -> float | None:
    """Least-squares slope [N/s] of the window, centred for accuracy; None if it spans no time."""
    count = len(times_ns)
    if count < 3:
        return None
    t0 = times_ns[-1]
    ts = [(t - t0) * 1e-9 for t in times_ns]
    t_mean = sum(ts) / count
    f_mean = sum(forces_n) / count
    sxx = 0.0
    sxf = 0.0
    for t, f in zip(ts, forces_n, strict=True):
        dt = t - t_mean
        sxx += dt * dt
        sxf += dt * (f - f_mean)
    return sxf / sxx if sxx > 0.0 else None


def noise_sigma_n(params: DetectorParams, state: DetectorState) -> float:
    """The detector's current estimate of the load-cell noise σ [N] (at least `noise_floor_n`)."""
    return max(state.scale_n / _MEAN_ABS_DIFF_PER_SIGMA, params.noise_floor_n)


def _estimates(
    params: DetectorParams, state: DetectorState, time_ns: int, dt_s: float, force_n: float
) -> tuple[int, bool, float, float, float]:
    """Updated (increments, warmed, rate, scale) and this sample's residual about the ramp trend.

    The ramp increment per sample and the mean |residual| are running means (equal weights while
    warming up, then exponential with the configured time constants), fed residuals clipped at
    `_CLIP` mean |residuals|: a robust running estimate of trend and noise from the increments.
    """
    if state.last_time_ns is None:
        return 0, False, 0.0, 0.0, 0.0
    increment = force_n - state.previous_force_n
    residual = increment - state.rate_n
    count = state.increments
    if not state.warmed:
        count += 1
        rate = state.rate_n + residual / count
        scale = state.scale_n + (abs(residual) - state.scale_n) / count
        # Over once warmup_s has passed to within half a sample period (so sample times a few µs
        # early do not add a sample: at 1000/s, exactly the 16 increments of the count before).
        elapsed_ns = time_ns - state.first_time_ns
        warmed = count >= WARMUP_MIN_INCREMENTS and elapsed_ns + 0.5 * dt_s * 1e9 >= params.warmup_s * 1e9
        return count, warmed, rate, scale, residual
    limit = _CLIP * state.scale_n
    clipped = min(max(residual, -limit), limit)
    rate = state.rate_n + min(dt_s / params.trend_window_s, 1.0) * clipped
    scale = state.scale_n + min(dt_s / params.noise_window_s, 1.0) * (abs(clipped) - state.scale_n)
    return count, True, rate, scale, residual


def detector_step(
    params: DetectorParams, state: DetectorState, time_ns: int, force_n: float
) -> tuple[DetectorState, SlipEvent | None]:
    """Advance the detector by one sample; return the new state and the slip it detected, if any.

    Raises ValueError for a non-finite force or a time earlier than the previous sample's.
    """
    if not math.isfinite(force_n):
        raise ValueError(f"force_n = {force_n!r} at time_ns = {time_ns}; allowed: finite")
    last = state.last_time_ns
    if last is not None and time_ns < last:
        raise ValueError(
            f"time_ns = {time_ns} is earlier than the previous sample ({last}); allowed: >= {last}"
        )

    window_t = state.window_times_ns
    window_f = state.window_forces_n
    if params.slope_n_per_s is not None:
        oldest = time_ns - int(params.slope_window_s * 1e9)
        start = 0
        while start < len(window_t) and window_t[start] < oldest:
            start += 1
        window_t = (*window_t[start:], time_ns)
        window_f = (*window_f[start:], force_n)

    dt_s = 0.0 if last is None else (time_ns - last) * 1e-9
    increments, warmed, rate, scale, residual = _estimates(params, state, time_ns, dt_s, force_n)
    low2 = force_n if last is None else min(force_n, state.previous_force_n)
    high2 = force_n if last is None else max(force_n, state.previous_force_n)
    ramp_aware = params.drop_ramp_s is not None
    idle = DetectorState(
        DetectorPhase.IDLE,
        time_ns,
        previous_force_n=force_n,
        window_times_ns=window_t,
        window_forces_n=window_f,
        increments=increments,
        rate_n=rate,
        scale_n=scale,
        first_time_ns=time_ns if last is None else state.first_time_ns,
        warmed=warmed,
    )
    if ramp_aware:
        older, rise = (
            (force_n, 0.0)
            if last is None
            else (state.previous_force_n, state.previous_force_n - state.older_force_n)
        )
        idle = idle._replace(older_force_n=older, older_rise_n=rise)

    phase = state.phase
    if phase is DetectorPhase.IDLE:
        if force_n >= params.arm_threshold_n:
            return idle._replace(
                phase=DetectorPhase.ARMED,
                peak_force_n=force_n,
                peak_time_ns=time_ns,
                cusum_onset_ns=time_ns,
                robust_peak_n=low2,
                leaky_peak_n=low2,
                trend_onset_ns=time_ns,
                armed_at_n=low2,
                drop_peak_n=low2,
            ), None
        return idle, None

    if phase is DetectorPhase.LATCHED:
        if force_n < params.rearm_level_n:
            return idle, None
        return _latched_step(params, state, idle, low2, high2, dt_s), None

    # Armed.
    peak_force = state.peak_force_n
    peak_time = state.peak_time_ns
    if force_n >= peak_force:
        peak_force = force_n
        peak_time = time_ns
    drop_n = peak_force - force_n

    cusum = state.cusum_n + (state.previous_force_n - force_n) - params.cusum_drift_n_per_s * dt_s
    cusum_onset = state.cusum_onset_ns
    if cusum <= 0.0:
        cusum = 0.0
        cusum_onset = time_ns  # the onset is the last sample at which the CUSUM was zero

    robust_peak = max(state.robust_peak_n, low2)
    leaky_peak = max(state.leaky_peak_n - params.peak_leak_n_per_s * dt_s, low2)
    drop_peak = max(state.drop_peak_n - params.drop_leak_n_per_s * dt_s, low2)
    sigma = max(state.scale_n / _MEAN_ABS_DIFF_PER_SIGMA, params.noise_floor_n)
    # Clipped residuals: a single-sample spike adds at most a few σ. Capped at twice the threshold:
    # the end of a ramp (a hold) also deviates from the trend, and must be forgotten within
    # 2·creep_k·σ / creep_drift_n_per_s rather than kept until a slow drift sags below the peak.
    limit = _CLIP * _MEAN_ABS_DIFF_PER_SIGMA * sigma
    trend_cusum = state.trend_cusum_n - min(max(residual, -limit), limit) - params.creep_drift_n_per_s * dt_s
    if params.creep_k is not None:
        trend_cusum = min(trend_cusum, 2.0 * params.creep_k * sigma)
    trend_onset = state.trend_onset_ns
    if trend_cusum <= 0.0:
        trend_cusum = 0.0
        trend_onset = time_ns

    triggers: list[str] = []
    onset = time_ns
    # The percentage drop compares spike-robust levels (max of the last two samples against the peak
    # of min(f[k−1], f[k])): one spike up and one down no longer make a drop. The peak decays at
    # drop_leak_n_per_s: noise maxima on the high side of a slow drift and the low side later, on a
    # cell with 10x the noise, made a percentage "drop" of a quiet hold.
    if ramp_aware and params.spike_samples == 2.0 and _ramp_predicted_peak(state):
        drop_peak = max(drop_peak, state.previous_force_n)
    level_peak, level = (drop_peak, high2) if params.spike_samples == 2.0 else (peak_force, force_n)
    if params.drop_ramp_s is not None and last is not None and time_ns > last and level < level_peak:
        # Where the ramp would have taken the peak since (the rate before this sample: a drop's own
        # samples must not lower it), for at most drop_ramp_s: at a low rate the line re-tensions
        # between two samples by a good share of a small drop.
        carried_ns = min(time_ns - peak_time, params.drop_ramp_s * 1e9)
        carried_n = max(state.rate_n, 0.0) * carried_ns / (time_ns - last)
        if params.drop_fraction is not None:
            # At most half the drop: the carry alone never makes one. While warming up, the rate is
            # the plain mean increment since the start, the fast phase's steps included, and the
            # line resting after the fast phase would fall short of that carried peak by a "drop".
            carried_n = min(carried_n, 0.5 * params.drop_fraction * level_peak)
        level_peak += carried_n
        if params.spike_samples == 2.0 and params.drop_fraction is not None:
            # ... and the newer sample of the pair need only be half the drop below the peak: the
            # winch takes the line up again after a slip, by a good part of it in one sample period.
            level = max(state.previous_force_n, force_n - 0.5 * params.drop_fraction * level_peak)
            # ... or, when the older sample had already fallen clearly below the one before it (a
            # slide caught part-way, or a fall that began just before that sample), the newer alone:
            # a single low spike follows no fall. The fall counts from 4 noise σ, or from min_drop_n
            # where that is less: a fast phase seen while warming up inflates σ for a noise window
            # (10 s at 10/s).
            older_fall = state.older_force_n - state.previous_force_n
            if older_fall > 0.0 and older_fall >= min(_FALLING_SIGMA * sigma, params.min_drop_n):
                level = min(level, force_n)
    robust_drop = level_peak - level
    if (
        params.drop_fraction is not None
        and robust_drop > 0.0
        and robust_drop >= params.min_drop_n
        and robust_drop >= params.drop_fraction * level_peak
    ):
        triggers.append("drop")
        onset = peak_time
    if drop_n >= params.min_drop_n and drop_n > 0.0:
        if params.slope_n_per_s is not None:
            slope = _window_slope_n_per_s(window_t, window_f)
            if slope is not None and slope <= -params.slope_n_per_s:
                triggers.append("slope")
                onset = peak_time
        if params.cusum_threshold_n is not None and cusum > params.cusum_threshold_n:
            triggers.append("cusum")
            onset = min(onset, cusum_onset)
    # The noise-scaled triggers wait for a rise since arming: a detector re-armed part-way down a
    # drop (a re-arm level above the arm threshold) must not fire again on the rest of that drop.
    warm = warmed and robust_peak - state.armed_at_n >= 2.0 * sigma
    if warm and params.noise_k is not None and leaky_peak - high2 >= params.noise_k * sigma:
        triggers.append("noise")
        onset = min(onset, peak_time)
    if (
        warm
        and params.creep_k is not None
        and trend_cusum >= params.creep_k * sigma
        and robust_peak - high2 >= params.creep_k * sigma
    ):
        triggers.append("creep")
        # The CUSUM's last zero wanders early in noise; the sag cannot start before the peak.
        onset = min(onset, max(trend_onset, peak_time))

    if triggers:
        slow = triggers == ["creep"] or time_ns - onset >= params.creep_min_s * 1e9
        kind = SlipEventKind.CREEP if slow else SlipEventKind.DROP
        event = SlipEvent(
            onset_time_ns=onset,
            detection_time_ns=time_ns,
            peak_time_ns=peak_time,
            peak_force_n=peak_force,
            force_after_n=force_n,
            drop_fraction=drop_n / peak_force if peak_force > 0.0 else 0.0,
            trigger="+".join(triggers),
            kind=kind,
        )
        return idle._replace(phase=DetectorPhase.LATCHED), event
    return DetectorState(
        DetectorPhase.ARMED,
        time_ns,
        peak_force,
        peak_time,
        force_n,
        cusum,
        cusum_onset,
        window_t,
        window_f,
        increments,
        rate,
        scale,
        robust_peak,
        leaky_peak,
        trend_cusum,
        trend_onset,
        state.armed_at_n,
        drop_peak_n=drop_peak,
        older_force_n=idle.older_force_n,
        older_rise_n=idle.older_rise_n,
        first_time_ns=idle.first_time_ns,
        warmed=warmed,
    ), None


def _ramp_predicted_peak(state: DetectorState) -> bool:
    """Whether f[k−1], a sample above f[k−2], is where the ramp took the line rather than a spike.

    Its rise is at most twice the rise before it (the winch may speed up between two samples; a
    spike on a ramp rises many times the ramp's step). At a low rate the fast phase can take the
    line onto the slip load in one sample, so the peak is a single sample: the two-sample guard
    alone would see no drop, and wait for the next slip.
    """
    rise = state.previous_force_n - state.older_force_n
    return state.older_rise_n > 0.0 and 0.0 < rise <= 2.0 * state.older_rise_n


def _train_samples(params: DetectorParams, dt_s: float) -> int:
    """The stick-slip window in samples: `train_window_s` at this sample's period, at least the minimum."""
    if dt_s <= 0.0:
        return TRAIN_MIN_SAMPLES
    return max(TRAIN_MIN_SAMPLES, round(params.train_window_s / dt_s))


def _latched_step(
    params: DetectorParams, state: DetectorState, idle: DetectorState, low2: float, high2: float, dt_s: float
) -> DetectorState:
    """The latched detector's next state: it counts a further drop (a stick-slip) when it sees one."""
    window = _train_samples(params, dt_s)
    levels = state.train_levels_n[-window:]
    drops = state.train_drops
    if params.train_k is not None and len(levels) == window:
        threshold = params.train_k * max(state.scale_n / _MEAN_ABS_DIFF_PER_SIGMA, params.noise_floor_n)
        fall = max(levels) - high2
        sag = (levels[0] + levels[1] + levels[2] - levels[-4] - levels[-3] - levels[-2]) / 3.0
        if fall >= threshold and sag <= max(_TRAIN_STEADY * fall, _TRAIN_STEADY_FLOOR * threshold):
            return idle._replace(phase=DetectorPhase.LATCHED, train_drops=drops + 1)
    levels = (*levels[1:], low2) if len(levels) == window else (*levels, low2)
    return idle._replace(phase=DetectorPhase.LATCHED, train_levels_n=levels, train_drops=drops)


def detector_run(
    params: DetectorParams,
    state: DetectorState,
    times_ns: Sequence[int],
    forces_n: Sequence[float],
    start: int = 0,
) -> tuple[DetectorState, int, SlipEvent | None]:
    """`detector_step` over `times_ns[start:]`/`forces_n[start:]` until a sample fires.

    Returns (the state after the last sample stepped, the index of the sample that fired or
    `len(times_ns)`, the event or None). The same states and events as calling `detector_step`
    sample by sample: the runner's ramp feeds its 1 kHz samples through this.

    Fast path: the quiet stretches (idle below the arm threshold, or armed with no trigger
    condition met, past the warm-up, with every `QuietUse.GATE` field of `QUIET_STRETCH_FIELDS`
    None: without the slope window) are stepped by `_quiet_stretch`, the
    same arithmetic on local variables without a state per sample; every other sample (arming,
    a trigger, the latch, the warm-up, bad input) goes through the plain `detector_step`.
    tests/test_slip_detector_fast_path.py holds both equal on simulated recordings.
    """
    count = len(times_ns)
    if len(forces_n) != count:
        raise ValueError(f"{count} times but {len(forces_n)} forces; allowed: one force per time")
    quiet_ok = all(getattr(params, name) is None for name in _QUIET_GATES)
    i = start
    while i < count:
        if (
            quiet_ok
            and state.phase is not DetectorPhase.LATCHED
            and state.last_time_ns is not None
            and state.warmed
        ):
            state, i = _quiet_stretch(params, state, times_ns, forces_n, i)
            if i >= count:
                break
        state, event = detector_step(params, state, times_ns[i], forces_n[i])
        if event is not None:
            return state, i, event
        i += 1
    return state, count, None


def _quiet_stretch(
    params: DetectorParams, state: DetectorState, times_ns: Sequence[int], forces_n: Sequence[float], i: int
) -> tuple[DetectorState, int]:
    """Fast path of `detector_run`: step while nothing but the running values can change.

    Returns the state before the first sample that needs the plain `detector_step` (and its index),
    or after the last sample. Each line mirrors `_estimates` and `detector_step` (same operations
    in the same order; min/max spelled out with the builtins' tie rules), for an idle or armed
    state past the warm-up and a detector without the slope window.
    """
    first = i
    armed = state.phase is DetectorPhase.ARMED
    last, prev = state.last_time_ns, state.previous_force_n
    assert last is not None
    rate, scale = state.rate_n, state.scale_n
    peak_f, peak_t = state.peak_force_n, state.peak_time_ns
    cusum, cusum_onset = state.cusum_n, state.cusum_onset_ns
    robust, leaky, drop_peak = state.robust_peak_n, state.leaky_peak_n, state.drop_peak_n
    trend, trend_onset, armed_at = state.trend_cusum_n, state.trend_onset_ns, state.armed_at_n
    arm_n = params.arm_threshold_n
    trend_window, noise_window = params.trend_window_s, params.noise_window_s
    cusum_drift, cusum_threshold = params.cusum_drift_n_per_s, params.cusum_threshold_n
    peak_leak, drop_leak = params.peak_leak_n_per_s, params.drop_leak_n_per_s
    creep_drift = params.creep_drift_n_per_s
    floor, noise_k, creep_k = params.noise_floor_n, params.noise_k, params.creep_k
    drop_fraction, min_drop = params.drop_fraction, params.min_drop_n
    spike2 = params.spike_samples == 2.0
    clip_sigma = _CLIP * _MEAN_ABS_DIFF_PER_SIGMA
    count = len(times_ns)
    while i < count:
        t, f = times_ns[i], forces_n[i]
        if f - f != 0.0 or t < last:
            break  # not finite, or back in time: the plain step raises
        dt_s = (t - last) * 1e-9
        residual = (f - prev) - rate
        limit = _CLIP * scale
        clipped = -limit if -limit > residual else residual
        clipped = limit if limit < clipped else clipped
        w = dt_s / trend_window
        new_rate = rate + (1.0 if w > 1.0 else w) * clipped
        w = dt_s / noise_window
        new_scale = scale + (1.0 if w > 1.0 else w) * (abs(clipped) - scale)
        if not armed:
            if f >= arm_n:
                break  # arming: the plain step
            last, prev, rate, scale = t, f, new_rate, new_scale
            i += 1
            continue
        new_peak_f, new_peak_t = (f, t) if f >= peak_f else (peak_f, peak_t)
        drop_n = new_peak_f - f
        new_cusum = cusum + (prev - f) - cusum_drift * dt_s
        new_cusum_onset = cusum_onset
        if new_cusum <= 0.0:
            new_cusum, new_cusum_onset = 0.0, t
        low2 = prev if prev < f else f  # min(f, prev)
        high2 = prev if prev > f else f  # max(f, prev)
        new_robust = low2 if low2 > robust else robust
        x = leaky - peak_leak * dt_s
        new_leaky = low2 if low2 > x else x
        x = drop_peak - drop_leak * dt_s
        new_drop_peak = low2 if low2 > x else x
        x = scale / _MEAN_ABS_DIFF_PER_SIGMA
        sigma = floor if floor > x else x
        limit = clip_sigma * sigma
        x = -limit if -limit > residual else residual
        x = limit if limit < x else x
        new_trend = trend - x - creep_drift * dt_s
        if creep_k is not None:
            cap = 2.0 * creep_k * sigma
            new_trend = cap if cap < new_trend else new_trend
        new_trend_onset = trend_onset
        if new_trend <= 0.0:
            new_trend, new_trend_onset = 0.0, t
        level_peak, level = (new_drop_peak, high2) if spike2 else (new_peak_f, f)
        robust_drop = level_peak - level
        warm = new_robust - armed_at >= 2.0 * sigma
        if (
            (
                drop_fraction is not None
                and robust_drop > 0.0
                and robust_drop >= min_drop
                and robust_drop >= drop_fraction * level_peak
            )
            or (
                cusum_threshold is not None
                and drop_n >= min_drop
                and drop_n > 0.0
                and new_cusum > cusum_threshold
            )
            or (warm and noise_k is not None and new_leaky - high2 >= noise_k * sigma)
            or (
                warm
                and creep_k is not None
                and new_trend >= creep_k * sigma
                and new_robust - high2 >= creep_k * sigma
            )
        ):
            break  # a trigger: the plain step builds the event
        last, prev, rate, scale = t, f, new_rate, new_scale
        peak_f, peak_t, cusum, cusum_onset = new_peak_f, new_peak_t, new_cusum, new_cusum_onset
        robust, leaky, drop_peak = new_robust, new_leaky, new_drop_peak
        trend, trend_onset = new_trend, new_trend_onset
        i += 1
    if i == first:
        return state, i
    if armed:
        out = DetectorState(
            DetectorPhase.ARMED,
            last,
            peak_f,
            peak_t,
            prev,
            cusum,
            cusum_onset,
            state.window_times_ns,
            state.window_forces_n,
            state.increments,
            rate,
            scale,
            robust,
            leaky,
            trend,
            trend_onset,
            armed_at,
            drop_peak_n=drop_peak,
            first_time_ns=state.first_time_ns,
            warmed=True,
        )
    else:
        out = DetectorState(
            DetectorPhase.IDLE,
            last,
            previous_force_n=prev,
            window_times_ns=state.window_times_ns,
            window_forces_n=state.window_forces_n,
            increments=state.increments,
            rate_n=rate,
            scale_n=scale,
            first_time_ns=state.first_time_ns,
            warmed=True,
        )
    return out, i


def further_drops(
    params: DetectorParams, state: DetectorState, times_ns: Iterable[int], forces_n: Iterable[float]
) -> tuple[DetectorState, int]:
    """Step on from `state` (the detector's state just after an event) over the following samples.

    Returns the state after them and how many further drops they held: drops counted while latched
    (`train_k`) plus events fired after a re-arm. One or more make the event a stick-slip train.
    """
    drops = 0
    for time_ns, force_n in zip(times_ns, forces_n, strict=True):
        before = state.train_drops if state.phase is DetectorPhase.LATCHED else 0
        state, event = detector_step(params, state, int(time_ns), float(force_n))
        if event is not None or (state.phase is DetectorPhase.LATCHED and state.train_drops > before):
            drops += 1
    return state, drops


def detect_slips(
    params: DetectorParams, times_ns: Iterable[int], forces_n: Iterable[float]
) -> list[SlipEvent]:
    """Run the step function over a whole recording; the events in order (used by replay)."""
    times = [int(t) for t in times_ns]
    forces = [float(f) for f in forces_n]
    if len(times) != len(forces):
        raise ValueError(f"{len(times)} times but {len(forces)} forces; allowed: one force per time")
    state = detector_init(params)
    events: list[SlipEvent] = []
    for time_ns, force_n in zip(times, forces, strict=True):
        state, event = detector_step(params, state, time_ns, force_n)
        if event is not None:
            events.append(event)
    return events
