"""Slip detection on the line-tension signal: a pure step function over (time, force) samples.

The runner steps it live in the acquisition loop (up to 1 kHz) and `rig replay` steps it again over
the logged samples; both call the same `detector_step`, so both find the same events.

Detector (docs/model.md §7):
1. **Arm** when the force reaches `arm_threshold_n`: below it the signal is handling noise.
2. While armed, **track the running peak** (a plateau's peak time is its last sample at the peak).
3. **Fire** on any enabled trigger, always only once the force is at least `min_drop_n` below the peak
   (so noise alone never fires):
   * `drop`: the force has fallen by `drop_fraction` of the peak (force <= (1 − d)·peak);
   * `slope`: the least-squares slope over the last `slope_window_s` is <= −`slope_n_per_s`;
   * `cusum`: a one-sided CUSUM of force decrements, `g ← max(g + (f[k−1] − f[k]) − drift, 0)`,
     exceeds `cusum_threshold_n`; its onset is the last sample at which g was 0.
4. **Latch** after firing: the detector ignores the signal until the force falls below
   `rearm_below_n`, then waits to arm again. So one slip fires once, and stick-slip fires once per
   drop that releases the line below the re-arm level. The default re-arm level is half the arm
   threshold: re-arming right at the arm threshold would let load-cell noise around it arm the
   detector on the unloading ramp after a slip, and that (real) decline would fire a second event.

Event times: `onset_time_ns` is the earliest onset the firing triggers point to (the peak time for
drop and slope, the CUSUM onset for cusum); `detection_time_ns` is the sample that fired.

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
from dataclasses import dataclass, fields
from enum import StrEnum
from typing import Any, NamedTuple

_NONE_WORDS = frozenset({"none", "null", "off", "disabled", ""})


@dataclass(frozen=True)
class _FieldRule:
    optional: bool
    minimum: float
    minimum_inclusive: bool
    maximum: float
    maximum_inclusive: bool

    def allowed(self) -> str:
        lo = "[" if self.minimum_inclusive else "("
        hi = "]" if self.maximum_inclusive else ")"
        text = f"a number in {lo}{self.minimum:g}, {self.maximum:g}{hi}"
        return text + " or none (disabled)" if self.optional else text

    def accepts(self, value: float) -> bool:
        above = value >= self.minimum if self.minimum_inclusive else value > self.minimum
        below = value <= self.maximum if self.maximum_inclusive else value < self.maximum
        return math.isfinite(value) and above and below


_RULES: dict[str, _FieldRule] = {
    "arm_threshold_n": _FieldRule(False, 0.0, False, 1e6, True),
    "drop_fraction": _FieldRule(True, 0.0, False, 1.0, False),
    "min_drop_n": _FieldRule(False, 0.0, True, 1e6, True),
    "slope_n_per_s": _FieldRule(True, 0.0, False, 1e9, True),
    "slope_window_s": _FieldRule(False, 0.0, False, 10.0, True),
    "cusum_threshold_n": _FieldRule(True, 0.0, False, 1e6, True),
    "cusum_drift_n": _FieldRule(False, 0.0, True, 1e6, True),
    "rearm_below_n": _FieldRule(True, 0.0, False, 1e6, True),
}


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
        cusum_drift_n: per-sample drift subtracted in the CUSUM, [0, 1e6] N.
        rearm_below_n: after firing, wait until the force is below this before arming again,
            (0, 1e6] N; None: half the arm threshold (a hysteresis band against noise).
    """

    arm_threshold_n: float = 1.0
    drop_fraction: float | None = 0.15
    min_drop_n: float = 0.2
    slope_n_per_s: float | None = None
    slope_window_s: float = 0.02
    cusum_threshold_n: float | None = None
    cusum_drift_n: float = 0.05
    rearm_below_n: float | None = None

    def __post_init__(self) -> None:
        """Validate every field (a direct construction is checked like `from_mapping`)."""
        for name, rule in _RULES.items():
            object.__setattr__(self, name, _checked(name, getattr(self, name), rule, "detector"))
        if self.drop_fraction is None and self.slope_n_per_s is None and self.cusum_threshold_n is None:
            raise ValueError(
                "detector: no trigger enabled; allowed: set at least one of drop_fraction, "
                "slope_n_per_s, cusum_threshold_n"
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
            if name not in _RULES:
                raise ValueError(
                    f"{source}: unknown field {name!r}{_suggestion(name)}; allowed: {_field_list()}"
                )
            values[name] = _checked(name, raw, _RULES[name], source)
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
        """Every field by name (None for disabled triggers): log it, re-apply it with `from_mapping`."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _field_list() -> str:
    return ", ".join(_RULES)


def _suggestion(name: str) -> str:
    close = difflib.get_close_matches(name, list(_RULES), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _checked(name: str, raw: Any, rule: _FieldRule, source: str) -> float | None:
    """`raw` as a validated float (or None for a disabled optional field); ValueError otherwise."""
    if raw is None or (isinstance(raw, str) and raw.strip().lower() in _NONE_WORDS):
        if rule.optional:
            return None
        raise ValueError(f"{source}: {name} is required; allowed: {rule.allowed()}")
    if isinstance(raw, bool):
        raise ValueError(f"{source}: {name} = {raw!r}; allowed: {rule.allowed()}")
    try:
        value = float(raw)
    except (TypeError, ValueError):
        raise ValueError(f"{source}: {name} = {raw!r} is not a number; allowed: {rule.allowed()}") from None
    if not rule.accepts(value):
        raise ValueError(f"{source}: {name} = {raw!r}; allowed: {rule.allowed()}")
    return value


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
        trigger: the triggers that fired on that sample, joined by '+' ('drop', 'slope', 'cusum').
    """

    onset_time_ns: int
    detection_time_ns: int
    peak_time_ns: int
    peak_force_n: float
    force_after_n: float
    drop_fraction: float
    trigger: str


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

    phase = state.phase
    if phase is DetectorPhase.IDLE:
        if force_n >= params.arm_threshold_n:
            return DetectorState(
                DetectorPhase.ARMED, time_ns, force_n, time_ns, force_n, 0.0, time_ns, window_t, window_f
            ), None
        return DetectorState(DetectorPhase.IDLE, time_ns, 0.0, 0, force_n, 0.0, 0, window_t, window_f), None

    if phase is DetectorPhase.LATCHED:
        next_phase = DetectorPhase.IDLE if force_n < params.rearm_level_n else DetectorPhase.LATCHED
        return DetectorState(next_phase, time_ns, 0.0, 0, force_n, 0.0, 0, window_t, window_f), None

    # Armed.
    peak_force = state.peak_force_n
    peak_time = state.peak_time_ns
    if force_n >= peak_force:
        peak_force = force_n
        peak_time = time_ns
    drop_n = peak_force - force_n

    cusum = state.cusum_n + (state.previous_force_n - force_n) - params.cusum_drift_n
    cusum_onset = state.cusum_onset_ns
    if cusum <= 0.0:
        cusum = 0.0
        cusum_onset = time_ns  # the onset is the last sample at which the CUSUM was zero

    triggers: list[str] = []
    onset = time_ns
    if drop_n >= params.min_drop_n and drop_n > 0.0:
        if params.drop_fraction is not None and drop_n >= params.drop_fraction * peak_force:
            triggers.append("drop")
            onset = peak_time
        if params.slope_n_per_s is not None:
            slope = _window_slope_n_per_s(window_t, window_f)
            if slope is not None and slope <= -params.slope_n_per_s:
                triggers.append("slope")
                onset = peak_time
        if params.cusum_threshold_n is not None and cusum > params.cusum_threshold_n:
            triggers.append("cusum")
            onset = min(onset, cusum_onset)

    if triggers:
        event = SlipEvent(
            onset_time_ns=onset,
            detection_time_ns=time_ns,
            peak_time_ns=peak_time,
            peak_force_n=peak_force,
            force_after_n=force_n,
            drop_fraction=drop_n / peak_force if peak_force > 0.0 else 0.0,
            trigger="+".join(triggers),
        )
        return DetectorState(
            DetectorPhase.LATCHED, time_ns, 0.0, 0, force_n, 0.0, 0, window_t, window_f
        ), event
    return DetectorState(
        DetectorPhase.ARMED, time_ns, peak_force, peak_time, force_n, cusum, cusum_onset, window_t, window_f
    ), None


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
