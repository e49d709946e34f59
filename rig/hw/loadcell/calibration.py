"""Load-cell calibration: the value type, tare and two-point math, JSON files, and the operator procedure.

force_n = (raw - offset_counts) * factor_n_per_count. A two-point calibration takes the mean raw
count with no load (the tare, which is also the offset) and with a reference mass hanging on the
line: factor = reference_kg * g / (raw_ref - raw_zero). Files are JSON, written atomically.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
import statistics
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from enum import Enum
from pathlib import Path
from typing import Any

from model.gravity import STANDARD_GRAVITY_M_S2
from rig.errors import InputError, RigError
from rig.files import atomic_write_text, read_text_file
from rig.hw.seams import Clock, LoadCell, LoadCellSample

CALIBRATION_KIND = "rig.loadcell.calibration"
CALIBRATION_VERSION = 1
INDICATOR_UNIT_MASS_KG = {"kg": 1.0, "g": 1e-3, "t": 1e3, "lb": 0.45359237}
INDICATOR_UNIT_FORCE_N = {"N": 1.0, "kN": 1e3}


class CalibrationError(RigError):
    """The calibration could not be completed (load did not change, no samples, operator aborted)."""


@dataclass(frozen=True, slots=True)
class Calibration:
    """Counts-to-newtons conversion of one load cell, with where it came from."""

    factor_n_per_count: float
    offset_counts: float
    reference_mass_kg: float | None  # None when not from a reference mass (e.g. an indicator's own units)
    g: float  # m/s^2 used to turn the reference mass into a force
    date: str  # ISO 8601, when the calibration was made
    serial: str  # the load cell's serial number (free text; "" when unknown)
    format: str  # line format it was made with (rig-lc1, indicator-st)
    noise_counts: float | None = None  # standard deviation of raw counts at zero load
    temperature_c: float | None = None

    def force_n(self, raw: float) -> float:
        """Force for a raw count."""
        return (raw - self.offset_counts) * self.factor_n_per_count

    def raw_for_force(self, force_n: float) -> float:
        """Raw count that reads as `force_n`."""
        return force_n / self.factor_n_per_count + self.offset_counts

    @property
    def noise_n(self) -> float | None:
        """Zero-load noise in newtons, when known."""
        return None if self.noise_counts is None else self.noise_counts * abs(self.factor_n_per_count)

    def with_tare(self, offset_counts: float) -> Calibration:
        """The same calibration re-zeroed at `offset_counts` (a tare before a trial)."""
        return replace(self, offset_counts=float(offset_counts))

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able form, with a kind and version header."""
        return {"kind": CALIBRATION_KIND, "version": CALIBRATION_VERSION, **asdict(self)}

    @classmethod
    def from_dict(cls, data: Any, source: str = "calibration") -> Calibration:
        """Validate a parsed JSON object; `InputError` naming `source` and the field otherwise."""
        if not isinstance(data, dict):
            raise InputError(f"{source}: top level must be a JSON object")
        if data.get("kind", CALIBRATION_KIND) != CALIBRATION_KIND:
            raise InputError(f"{source}: kind: {data.get('kind')!r}; allowed: {CALIBRATION_KIND!r}")
        if data.get("version", CALIBRATION_VERSION) != CALIBRATION_VERSION:
            raise InputError(f"{source}: version: {data.get('version')!r}; allowed: {CALIBRATION_VERSION}")

        def number(
            field: str, *, optional: bool = False, positive: bool = False, nonzero: bool = False
        ) -> Any:
            if field not in data or data[field] is None:
                if optional:
                    return None
                raise InputError(f"{source}: {field}: missing; required number")
            value = data[field]
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise InputError(f"{source}: {field}: {value!r}; allowed: a finite number")
            if positive and value <= 0:
                raise InputError(f"{source}: {field}: {value!r}; allowed: > 0")
            if nonzero and value == 0:
                raise InputError(f"{source}: {field}: 0; allowed: any non-zero number")
            return float(value)

        def text(field: str) -> str:
            value = data.get(field)
            if not isinstance(value, str):
                raise InputError(f"{source}: {field}: {value!r}; allowed: a string")
            return value

        date = text("date")
        try:
            dt.datetime.fromisoformat(date)
        except ValueError:
            raise InputError(f"{source}: date: {date!r}; allowed: an ISO 8601 date/time") from None
        noise = number("noise_counts", optional=True)
        if noise is not None and noise < 0:
            raise InputError(f"{source}: noise_counts: {noise!r}; allowed: >= 0")
        return cls(
            factor_n_per_count=number("factor_n_per_count", nonzero=True),
            offset_counts=number("offset_counts"),
            reference_mass_kg=number("reference_mass_kg", optional=True, positive=True),
            g=number("g", positive=True),
            date=date,
            serial=text("serial"),
            format=text("format"),
            noise_counts=noise,
            temperature_c=number("temperature_c", optional=True),
        )

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write as JSON atomically (readers see the old file or the new one)."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Calibration:
        """Read a calibration file; `InputError` naming the file (and field) when it is unusable."""
        p = Path(path)
        text = read_text_file(p, what="a calibration JSON file")
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(
                f"{p}: malformed JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
            ) from None
        return cls.from_dict(data, str(p))


def now_iso() -> str:
    """The current UTC time as ISO 8601 with seconds."""
    return dt.datetime.now(dt.UTC).replace(microsecond=0).isoformat()


def indicator_calibration(
    unit: str = "kg",
    decimals: int = 2,
    g: float = STANDARD_GRAVITY_M_S2,
    serial: str = "",
    date: str | None = None,
) -> Calibration:
    """Calibration for an `indicator-st` stream, whose raw value is already in `unit` (last digit = 1)."""
    step = 10.0**-decimals
    if unit in INDICATOR_UNIT_MASS_KG:
        factor = step * INDICATOR_UNIT_MASS_KG[unit] * g
    elif unit in INDICATOR_UNIT_FORCE_N:
        factor = step * INDICATOR_UNIT_FORCE_N[unit]
    else:
        allowed = ", ".join([*INDICATOR_UNIT_MASS_KG, *INDICATOR_UNIT_FORCE_N])
        raise InputError(f"indicator unit {unit!r}; allowed: {allowed}")
    return Calibration(factor, 0.0, None, g, date or now_iso(), serial, "indicator-st")


@dataclass(frozen=True, slots=True)
class Reading:
    """The mean and spread of raw counts over a window of samples."""

    mean_counts: float
    std_counts: float
    n: int


def tare(samples: Sequence[LoadCellSample] | Sequence[int]) -> Reading:
    """Average the raw counts of samples taken while the load was settled (the zero, or a reference)."""
    raws = [s.raw if isinstance(s, LoadCellSample) else int(s) for s in samples]
    if not raws:
        raise CalibrationError("no load-cell samples in the averaging window")
    std = statistics.pstdev(raws) if len(raws) > 1 else 0.0
    return Reading(statistics.fmean(raws), std, len(raws))


def two_point(
    zero: Reading,
    reference: Reading,
    reference_mass_kg: float,
    *,
    g: float = STANDARD_GRAVITY_M_S2,
    serial: str = "",
    format_name: str = "",
    date: str | None = None,
    temperature_c: float | None = None,
) -> Calibration:
    """Calibration from the zero reading and the reading with `reference_mass_kg` hanging."""
    if not reference_mass_kg > 0:
        raise InputError(f"reference mass {reference_mass_kg} kg; allowed: > 0")
    span = reference.mean_counts - zero.mean_counts
    noise = max(zero.std_counts, reference.std_counts, 1.0)
    if abs(span) < 10 * noise:
        raise CalibrationError(
            f"the reference mass changed the reading by only {span:.1f} counts (noise {noise:.1f} counts);"
            " is the mass hanging freely on the line?"
        )
    return Calibration(
        factor_n_per_count=reference_mass_kg * g / span,
        offset_counts=zero.mean_counts,
        reference_mass_kg=reference_mass_kg,
        g=g,
        date=date or now_iso(),
        serial=serial,
        format=format_name,
        noise_counts=zero.std_counts,
        temperature_c=temperature_c,
    )


def collect_samples(
    load_cell: LoadCell, clock: Clock, duration_s: float, poll_interval_s: float = 0.02
) -> list[LoadCellSample]:
    """Poll `load_cell` for `duration_s` on `clock` and return every sample received."""
    samples: list[LoadCellSample] = []
    end_ns = clock.monotonic_ns() + round(duration_s * 1e9)
    while True:
        samples.extend(load_cell.poll())
        now_ns = clock.monotonic_ns()
        if now_ns >= end_ns:
            return samples
        clock.sleep(min(poll_interval_s, (end_ns - now_ns) / 1e9))


class CalibrationStep(Enum):
    """What the operator is asked to do before each measurement."""

    REMOVE_LOAD = "remove_load"
    PLACE_REFERENCE = "place_reference"


def run_calibration(
    load_cell: LoadCell,
    prompt_fn: Callable[[CalibrationStep, str], None],
    reference_kg: float,
    settle_s: float,
    *,
    clock: Clock,
    average_s: float = 1.0,
    g: float = STANDARD_GRAVITY_M_S2,
    serial: str = "",
    format_name: str = "",
    temperature_c: float | None = None,
    progress_fn: Callable[[str], None] = lambda message: None,
) -> Calibration:
    """Walk through tare and reference mass on an open load cell; return the two-point calibration.

    For each step: `prompt_fn(step, message)` returns once the operator confirms (it raises to
    abort), then the load is left to settle for `settle_s` (samples discarded) and raw counts are
    averaged over `average_s`.
    """
    if not reference_kg > 0:
        raise InputError(f"--reference-kg {reference_kg}; allowed: > 0")
    if not settle_s >= 0 or not average_s > 0:
        raise InputError(f"--settle-s {settle_s}, --average-s {average_s}; allowed: settle >= 0, average > 0")

    def measure(step: CalibrationStep, message: str, what: str) -> Reading:
        prompt_fn(step, message)
        progress_fn(f"settling for {settle_s:g} s ...")
        collect_samples(load_cell, clock, settle_s)
        progress_fn(f"averaging {what} over {average_s:g} s ...")
        reading = tare(collect_samples(load_cell, clock, average_s))
        progress_fn(f"{what}: {reading.mean_counts:.1f} counts (std {reading.std_counts:.1f}, n={reading.n})")
        return reading

    load_cell.poll()  # drop whatever was buffered before the operator was ready
    zero = measure(
        CalibrationStep.REMOVE_LOAD,
        "Step 1/2: remove every load from the line (empty hook hanging freely), keep the rig still.",
        "zero",
    )
    reference = measure(
        CalibrationStep.PLACE_REFERENCE,
        f"Step 2/2: hang the {reference_kg:g} kg reference mass on the line and let it come to rest.",
        "reference",
    )
    return two_point(
        zero,
        reference,
        reference_kg,
        g=g,
        serial=serial,
        format_name=format_name,
        temperature_c=temperature_c,
    )
