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
from rig.hw.seams import Clock, LoadCell, LoadCellSample
from rig.inputs.files import atomic_write_text, load_json_file

CALIBRATION_KIND = "rig.loadcell.calibration"
CALIBRATION_VERSION = 1
INDICATOR_UNIT_MASS_KG = {"kg": 1.0, "g": 1e-3, "t": 1e3, "lb": 0.45359237}
INDICATOR_UNIT_FORCE_N = {"N": 1.0, "kN": 1e3}
# Ranges of a calibration file's numbers (docs/formats.md §6).
FACTOR_RANGE_N_PER_COUNT = (1e-12, 1e6)  # |factor|
COUNTS_LIMIT = 1e12  # |offset_counts|, noise_counts
REFERENCE_MASS_RANGE_KG = (1e-6, 1e4)
G_RANGE_M_S2 = (0.1, 100.0)
TEMPERATURE_RANGE_C = (-100.0, 200.0)


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
        """Validate a parsed JSON object; `InputError` naming `source` and the field otherwise.

        Every number has a range (docs/formats.md §6) wide enough for any load cell and narrow
        enough that converting counts to newtons and back cannot overflow.
        """
        if not isinstance(data, dict):
            raise InputError(f"{source}: top level must be a JSON object")
        if data.get("kind", CALIBRATION_KIND) != CALIBRATION_KIND:
            raise InputError(f"{source}: kind: {_short(data.get('kind'))}; allowed: {CALIBRATION_KIND!r}")
        version = data.get("version", CALIBRATION_VERSION)
        if isinstance(version, bool) or version != CALIBRATION_VERSION:
            raise InputError(f"{source}: version: {_short(version)}; allowed: {CALIBRATION_VERSION}")

        def number(field: str, bounds: tuple[float, float], *, optional: bool = False) -> Any:
            lo, hi = bounds
            magnitude = field == "factor_n_per_count"  # its sign follows the cell's wiring
            allowed = (
                f"a finite number with {lo:g} <= |x| <= {hi:g}"
                if magnitude
                else f"a finite number from {lo:g} to {hi:g}"
            )
            if field not in data or data[field] is None:
                if optional:
                    return None
                raise InputError(f"{source}: {field}: missing; allowed: {allowed} (required)")
            value = data[field]
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InputError(f"{source}: {field}: {_short(value)}; allowed: {allowed}")
            try:
                x = float(value)
            except OverflowError:  # an integer beyond the float range
                x = math.inf
            if not (math.isfinite(x) and lo <= (abs(x) if magnitude else x) <= hi):
                raise InputError(f"{source}: {field}: {_short(value)}; allowed: {allowed}")
            return x

        def text(field: str, max_chars: int) -> str:
            value = data.get(field)
            if not isinstance(value, str) or len(value) > max_chars:
                shown = "missing" if value is None else _short(value)
                raise InputError(
                    f"{source}: {field}: {shown}; allowed: a string of at most {max_chars} characters"
                )
            return value

        factor = number("factor_n_per_count", FACTOR_RANGE_N_PER_COUNT)
        offset = number("offset_counts", (-COUNTS_LIMIT, COUNTS_LIMIT))
        reference = number("reference_mass_kg", REFERENCE_MASS_RANGE_KG, optional=True)
        g = number("g", G_RANGE_M_S2)
        date = text("date", 64)
        try:
            dt.datetime.fromisoformat(date)
        except ValueError:
            raise InputError(f"{source}: date: {date!r}; allowed: an ISO 8601 date/time") from None
        return cls(
            factor_n_per_count=factor,
            offset_counts=offset,
            reference_mass_kg=reference,
            g=g,
            date=date,
            serial=text("serial", 256),
            format=text("format", 64),
            noise_counts=number("noise_counts", (0.0, COUNTS_LIMIT), optional=True),
            temperature_c=number("temperature_c", TEMPERATURE_RANGE_C, optional=True),
        )

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write as JSON atomically (readers see the old file or the new one)."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Calibration:
        """Read a calibration file; `InputError` naming the file (and field) when it is unusable."""
        p = Path(path)
        return cls.from_dict(load_json_file(p, what="a calibration JSON file"), str(p))


def _short(value: Any) -> str:
    if isinstance(value, int) and value.bit_length() > 100:
        return "an integer beyond the float range"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


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
        "Step 1/2: take every load off the line (slack, nothing on the hook), keep the rig still.",
        "zero",
    )
    reference = measure(
        CalibrationStep.PLACE_REFERENCE,
        f"Step 2/2: load the line through the cell with the reference: hang the {reference_kg:g} kg mass "
        "from it (over the pulley, so that the cell sits in the line as in a trial), or pull it to "
        f"{reference_kg * g:.4g} N read on a reference gauge; let it come to rest.",
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
