"""Re-detection: the slip detector run again over each trial's logged load-cell samples.

The runner initialises the detector at the trial's ramp start (the log time of its first
`ramp_fast`/`ramp_slow` phase) and feeds it every `/rig/loadcell` sample logged at or after that
time, in log order, until an event fires that the winch confirms. Replay feeds `detect_slips` the
same samples, from the ramp start to the start of the trial's `unloading` phase (or the trial's end),
and picks the event:

* with the logged parameters, the first event whose detection time is the logged one: a first
  event the runner rejected (winch backing off) latched the detector exactly as it did live, so the
  events after it are the live ones. The event must then equal the logged one field by field;
  anything else is a mismatch, reported.
* with other parameters (`--detector k=v ...`), the first event the winch confirms, judged as the
  runner does from the latest logged winch state at or before the event (velocity > -0.05 rad/s and
  no hardware error). That state is the one the runner read in the same control tick up to the
  tick's timing, so this reproduces the runner's choice in all but contrived cases.

Stick-slip trains: after the chosen event, the detector, latched by it, is stepped on over the
samples logged up to the protocol's `hold_after_slip_s` after the detection (as the runner did; up
to the unloading phase when the protocol is not attached), and counts further drops
(`further_drops`). With the logged parameters, a count that differs from the logged one (logs that
have it) is a mismatch.

Each trial is re-detected from its own samples (`rig.analysis.samples`), read from the log for it
alone; the winch states for the confirmation rule likewise (the latest one before the trial's span
read back from the log when the span has none before an event).

Overrides are validated like protocol fields: an unknown name or a bad value is an `InputError`
naming it and its allowed range.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
import pandas as pd

from model.slip_detector import (
    DetectorParams,
    DetectorState,
    SlipEvent,
    detector_init,
    detector_step,
    further_drops,
)
from rig.analysis.samples import TrialSamples, analysis_span, trial_samples
from rig.analysis.trials import TrialRecord
from rig.errors import InputError
from rig.log.format import schemas
from rig.log.reading.reader import RunLog
from rig.vocabulary import ServoRole

WINCH_BACKING_OFF_RAD_S = -0.05  # the runner's `_confirmed_by_winch` threshold

MATCH = "match"
MISMATCH = "mismatch"
CHANGED = "changed"
NO_SAMPLES = "no_samples"


@dataclass(frozen=True)
class Redetection:
    """The outcome of re-detecting one trial.

    `status`: `match` (the re-detected event, or its absence, equals what was logged), `mismatch`
    (it should have and does not: logged parameters), `changed` (it differs, as parameters given on
    the command line may make it), `no_samples` (no ramp window or no samples in it).
    """

    trial_id: int
    status: str
    event: SlipEvent | None
    logged: SlipEvent | None
    samples: int
    detail: str
    train_drops: int | None = None  # further drops after the event (None: no event)


def validate_overrides(assignments: Sequence[str]) -> None:
    """Check `key=value` overrides against the detector's fields (InputError naming the bad one)."""
    if not assignments:
        return
    try:
        DetectorParams().with_overrides(assignments, source="--detector")
    except ValueError as exc:
        raise InputError(str(exc)) from None


def detector_params(logged: DetectorParams | None, overrides: Sequence[str]) -> DetectorParams:
    """The logged detector parameters (defaults if none were logged) with `overrides` applied."""
    base = logged if logged is not None else DetectorParams()
    if not overrides:
        return base
    try:
        return base.with_overrides(overrides, source="--detector")
    except ValueError as exc:
        raise InputError(str(exc)) from None


def _same_event(event: SlipEvent, logged: SlipEvent) -> list[str]:
    """Fields in which a re-detected event differs from the logged one (empty: identical)."""
    differences = []
    for name in (f.name for f in fields(SlipEvent)):
        mine, theirs = getattr(event, name), getattr(logged, name)
        if mine != theirs:
            differences.append(f"{name} {mine!r} vs logged {theirs!r}")
    return differences


def _winch_rows(states: pd.DataFrame) -> pd.DataFrame:
    return states[states["role"] == ServoRole.WINCH] if "role" in states.columns else states.iloc[:0]


class WinchStates:
    """Latest logged winch state at a time, for the runner's confirmation rule.

    Holds the winch states of a span of log time; for a time before the first of them, the latest
    state before the span is read back from the log (once, when first needed).
    """

    def __init__(self, log: RunLog, first_ns: int, last_ns: int) -> None:
        self._log = log
        self._first_ns = first_ns
        self._before: tuple[float, int] | None = None
        self._before_read = False
        winch = _winch_rows(log.window(schemas.SERVO_STATE, first_ns, last_ns))
        if winch.empty:
            self.times = np.zeros(0, np.int64)
            return
        self.times = winch["log_time_ns"].to_numpy(np.int64)
        self.velocity = winch["velocity_rad_s"].to_numpy(float)
        self.error = winch["hardware_error"].to_numpy(np.int64)

    def confirms(self, time_ns: int) -> bool:
        i = int(np.searchsorted(self.times, time_ns, side="right")) - 1
        if i >= 0:
            return bool(self.velocity[i] > WINCH_BACKING_OFF_RAD_S and self.error[i] == 0)
        if not self._before_read:
            self._before_read = True
            row = self._log.last_before(schemas.SERVO_STATE, self._first_ns, _winch_rows)
            if row is not None:
                self._before = (float(row["velocity_rad_s"]), int(row["hardware_error"]))
        if self._before is None:
            return True  # nothing logged: no evidence of backing off
        velocity, error = self._before
        return bool(velocity > WINCH_BACKING_OFF_RAD_S and error == 0)


def redetect_trials(
    records: Sequence[TrialRecord],
    params: DetectorParams,
    *,
    exact: bool,
    hold_after_slip_s: float | None = None,
) -> list[Redetection]:
    """Re-detect every trial, one at a time; `exact` when `params` are the logged ones (module docstring)."""
    return [
        redetect_trial(
            record,
            trial_samples(record, hold_after_slip_s),
            params,
            exact=exact,
            hold_after_slip_s=hold_after_slip_s,
        )
        for record in records
    ]


def redetect_trial(
    record: TrialRecord,
    samples: TrialSamples,
    params: DetectorParams,
    *,
    exact: bool,
    hold_after_slip_s: float | None = None,
) -> Redetection:
    """Re-detect one trial from its samples (`samples.trial_samples` with the same hold)."""
    times, forces = samples.times_ns, samples.forces_n
    winch = None if exact else WinchStates(record.part.log, *analysis_span(record, hold_after_slip_s))
    found = _redetect_one(record, times, forces, winch, params, exact)
    return _with_train(found, record, times, forces, params, exact, hold_after_slip_s)


def _events_and_states(
    params: DetectorParams, times: np.ndarray, forces: np.ndarray
) -> tuple[list[SlipEvent], list[DetectorState]]:
    """`detect_slips` over the samples, with the detector's state right after each event."""
    state = detector_init(params)
    events: list[SlipEvent] = []
    states: list[DetectorState] = []
    for time_ns, force_n in zip(times.tolist(), forces.tolist(), strict=True):
        state, event = detector_step(params, state, time_ns, force_n)
        if event is not None:
            events.append(event)
            states.append(state)
    return events, states


def _with_train(
    found: Redetection,
    record: TrialRecord,
    times: np.ndarray,
    forces: np.ndarray,
    params: DetectorParams,
    exact: bool,
    hold_after_slip_s: float | None,
) -> Redetection:
    """`found` with the further drops after its event counted (and checked against the logged count)."""
    event = found.event
    if event is None or record.ramp_start_ns is None:
        return found
    lo = int(np.searchsorted(times, record.ramp_start_ns, side="left"))
    upto = int(np.searchsorted(times, event.detection_time_ns, side="right"))
    events, states = _events_and_states(params, times[lo:upto], forces[lo:upto])
    if not events or events[-1] != event:
        return found
    if hold_after_slip_s is not None:
        end = int(np.searchsorted(times, event.detection_time_ns + round(hold_after_slip_s * 1e9), "right"))
    else:
        unloading = record.unloading_ns if record.unloading_ns is not None else record.result.end_time_ns
        end = int(np.searchsorted(times, unloading, side="left"))
    _, drops = further_drops(params, states[-1], times[upto:end].tolist(), forces[upto:end].tolist())
    logged = record.train_drops
    if exact and found.status == MATCH and logged is not None and drops != logged:
        detail = f"{drops} further drops re-detected after the slip, {logged} logged"
        return replace(found, status=MISMATCH, detail=detail, train_drops=drops)
    return replace(found, train_drops=drops)


def _redetect_one(
    record: TrialRecord,
    times: np.ndarray,
    forces: np.ndarray,
    winch: WinchStates | None,
    params: DetectorParams,
    exact: bool,
) -> Redetection:
    logged = record.slip
    if record.ramp_start_ns is None:
        return Redetection(
            record.trial_id, NO_SAMPLES, None, logged, 0, "no ramp phase logged for this trial"
        )
    end_ns = record.unloading_ns if record.unloading_ns is not None else record.result.end_time_ns
    lo = int(np.searchsorted(times, record.ramp_start_ns, side="left"))
    hi = int(np.searchsorted(times, end_ns, side="left"))
    if hi <= lo:
        return Redetection(record.trial_id, NO_SAMPLES, None, logged, 0, "no load-cell samples in the ramp")
    events, _ = _events_and_states(params, times[lo:hi], forces[lo:hi])
    count = hi - lo
    if exact:
        if logged is None:
            if not events:
                return Redetection(record.trial_id, MATCH, None, None, count, "no slip, as logged")
            first = events[0]
            return Redetection(
                record.trial_id, MISMATCH, first, None, count,
                f"re-detected a slip at {first.peak_force_n:.4g} N that the run did not log",
            )  # fmt: skip
        chosen = next((e for e in events if e.detection_time_ns == logged.detection_time_ns), None)
        if chosen is None:
            detail = (
                f"no re-detected event at the logged detection time ({len(events)} events)"
                if events
                else "no event re-detected"
            )
            return Redetection(
                record.trial_id, MISMATCH, events[0] if events else None, logged, count, detail
            )
        differences = _same_event(chosen, logged)
        if differences:
            return Redetection(record.trial_id, MISMATCH, chosen, logged, count, "; ".join(differences))
        return Redetection(record.trial_id, MATCH, chosen, logged, count, "identical to the logged event")
    assert winch is not None  # read for re-detection with other parameters
    chosen = next((e for e in events if winch.confirms(e.detection_time_ns)), None)
    if chosen is None and logged is None:
        return Redetection(record.trial_id, MATCH, None, None, count, "no slip, as logged")
    if chosen is None:
        return Redetection(record.trial_id, CHANGED, None, logged, count, "no event with these parameters")
    if logged is not None and not _same_event(chosen, logged):
        return Redetection(record.trial_id, MATCH, chosen, logged, count, "identical to the logged event")
    if logged is None:
        return Redetection(
            record.trial_id,
            CHANGED,
            chosen,
            None,
            count,
            f"a slip at {chosen.peak_force_n:.4g} N, none logged",
        )
    shift = chosen.peak_force_n - logged.peak_force_n
    delay_s = (chosen.detection_time_ns - logged.detection_time_ns) / 1e9
    return Redetection(
        record.trial_id, CHANGED, chosen, logged, count,
        f"peak {chosen.peak_force_n:.4g} N ({shift:+.3g} N vs logged), detected {delay_s:+.3f} s, "
        f"force after {chosen.force_after_n:.4g} N",
    )  # fmt: skip
