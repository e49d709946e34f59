"""`rig fit DATA.csv`: the joint-estimation fit m = k/l with bounds, and the capacity and μs·δ0 it implies."""

from __future__ import annotations

import argparse
import contextlib
import csv
import difflib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from model.fit import DEFAULT_LEVEL, FitSummary, degenerate_reasons, nonnegative_bounds
from model.fit_keys import EstimateSummary, summarize_estimate
from model.gravity import PAPER_G_M_S2
from model.joint import CapacityConstant, resolve_constant
from model.k_estimators import DEFAULT_ESTIMATOR, ESTIMATOR_NAMES, check_estimator
from rig.cli.commands import COMMANDS
from rig.cli.output import emit_json, format_table
from rig.errors import InputError
from rig.inputs.files import read_text_file

DISTANCE_COLUMN = "distance_m"
MASS_COLUMN = "mass_kg"
FORCE_COLUMN = "force_n"
CENSORED_COLUMN = "censored"
ALLOWED_COLUMNS = (DISTANCE_COLUMN, MASS_COLUMN, FORCE_COLUMN, CENSORED_COLUMN)
ALLOWED_COLUMNS_TEXT = "distance_m and mass_kg (or force_n instead of mass_kg), optionally censored"
CENSORED_VALUES = {"0": False, "1": True, "false": False, "true": True, "": False}
# Ranges (docs/formats.md §4): wide for any bench, narrow enough that the fit's sums of 1/l² and m²
# neither overflow nor lose everything to subnormals.
DISTANCE_RANGE_M = (1e-4, 100.0)
MASS_RANGE_KG = (0.0, 1e4)
FORCE_RANGE_N = (0.0, 1e5)
RADIUS_RANGE_M = (1e-5, 1.0)
LEVEL_RANGE = (0.001, 0.999999)
G_RANGE_M_S2 = (0.1, 100.0)
CONSTANT_RANGE = (1e-3, 1e3)
SMALLEST_NONZERO = 1e-9  # kg or N: a mass or force below this (other than 0) is below any resolution

DESCRIPTION = """\
Fit the joint-estimation data (docs/model.md §4): slip masses m_s hung at distances l_s from a
joint follow m_s = k / l_s. From k: the joint capacity N_max = k·g [N·m] and
mu_s·delta0 = k·g / (c·R³) [Pa]. Estimators (--estimator):

  paper     the paper's least squares through the origin in 1/l with MATLAB cftool statistics
            (dfe = n - 1, bounds k ± t_{(1+level)/2, n-1}·se); assumes equal scatter everywhere
  weighted  the mean of m·l with a t interval; right when the scatter is proportional to m
  auto      (default) fits sd(m)² = a² + (b·m)² to the data, weights k by it, and says which
            scatter model the data support (likelihood-ratio tests); docs/model.md §4.2

The paper's fit is always shown beside the chosen one.

DATA.csv has a header line and one row per slip trial:

  # lines starting with '#' are comments
  distance_m,mass_kg
  0.05,3.21
  0.06,2.70

Columns: distance_m [m, 0.0001-100] and mass_kg [kg, 0 or 1e-9 to 1e4]; or force_n [N, 0 or 1e-9 to 1e5]
instead of mass_kg (the peak tension, converted with --g). Optional: censored (1/true: no slip up
to that load, so the mass is only a lower bound; 0/false/empty: a slip). Other columns are
ignored. Example: protocols/example_fit.csv.
"""

EPILOG = """\
The constant c (docs/model.md §2.1): 'paper' = 5.4397 as printed in the paper (default, so
mu_s·delta0 compares with it), 'derived' = pi² from the sphere integrals, or a positive number.
c changes mu_s·delta0 only; the capacity k·g does not depend on it.

JSON (--json): n, k, k_ci, sse, sst, r2, rmse, dfe, se, level, constant, c, radius_m,
mu_delta0_pa, mu_delta0_ci_pa, capacity_nm, capacity_ci_nm (the chosen estimator's), then
estimator, scatter_model, n_censored, n_excluded, note, scatter_a_kg, scatter_b, diagnostic,
paper (the paper's fit, same keys) and degenerate (why the fit says nothing about m = k/l; empty
for a sound fit). r2 is null when all masses are equal. The JSON bounds are the t intervals as
computed (cftool's for paper), below 0 too; the table shows them cut at 0 (marked *), as k, the
capacity and mu_s·delta0 cannot be negative. docs/formats.md §4.
Exit codes: 0 done, 2 invalid input (one line on stderr naming the file, row and column).
"""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig fit`."""
    parser = subparsers.add_parser(
        "fit",
        help=COMMANDS["fit"],
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("data", metavar="DATA.csv", help="CSV with distance_m and mass_kg (or force_n)")
    parser.add_argument(
        "--radius-m", required=True, metavar="R", help="ball radius R of the joint [m], 1e-5 to 1"
    )
    parser.add_argument(
        "--constant",
        default="paper",
        metavar="C",
        help="c in N_max = c·mu_s·delta0·R³: paper (5.4397, default), derived (pi²) or a number 0.001-1000",
    )
    parser.add_argument(
        "--level",
        default=str(DEFAULT_LEVEL),
        metavar="P",
        help=f"confidence level of the bounds, 0.001 to 0.999999 (default {DEFAULT_LEVEL})",
    )
    parser.add_argument(
        "--g",
        default=str(PAPER_G_M_S2),
        metavar="G",
        help=f"gravity [m/s²], 0.1 to 100 (default {PAPER_G_M_S2}, the paper's)",
    )
    parser.add_argument(
        "--estimator",
        default=DEFAULT_ESTIMATOR,
        metavar="NAME",
        help=f"{' | '.join(ESTIMATOR_NAMES)} (default {DEFAULT_ESTIMATOR}); the paper's fit is shown too",
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )
    parser.set_defaults(handler=run)


def _number_option(flag: str, text: str, bounds: tuple[float, float], unit: str, example: float) -> float:
    allowed = f"a number from {bounds[0]:g} to {bounds[1]:g}{unit}"
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{flag} {text!r} is not a number; allowed: {allowed}") from None
    if not bounds[0] <= value <= bounds[1]:  # NaN fails too
        raise InputError(f"{flag} {text}: allowed: {allowed}, e.g. {example:g}")
    return value


def _options(args: argparse.Namespace) -> tuple[float, CapacityConstant, float, float]:
    radius = _number_option("--radius-m", args.radius_m, RADIUS_RANGE_M, " [m]", 0.01)
    level = _number_option("--level", args.level, LEVEL_RANGE, "", DEFAULT_LEVEL)
    g = _number_option("--g", args.g, G_RANGE_M_S2, " [m/s²]", PAPER_G_M_S2)
    spec: str | float = args.constant
    with contextlib.suppress(ValueError):
        spec = float(args.constant)  # a number; else a name for resolve_constant
    lo, hi = CONSTANT_RANGE
    try:
        constant = resolve_constant(spec)
        if not lo <= constant.value <= hi:
            raise ValueError(constant.value)
    except ValueError:
        raise InputError(
            f"--constant {args.constant!r}: allowed: paper (5.4397), derived (pi²) or a number "
            f"from {lo:g} to {hi:g}"
        ) from None
    return radius, constant, level, g


@dataclass(frozen=True)
class FitData:
    """Pairs read from a fit CSV, with where each came from (for messages)."""

    distances_m: tuple[float, ...]
    masses_kg: tuple[float, ...]
    mass_source: str  # the column the masses came from
    censored: tuple[bool, ...] = ()  # per row: the mass is a lower bound (no slip); empty: none


def _header_error(path: Path, line: int, names: list[str], missing: str) -> InputError:
    unknown = [n for n in names if n and n not in ALLOWED_COLUMNS]
    hint = ""
    for name in unknown:
        close = difflib.get_close_matches(name, ALLOWED_COLUMNS, n=1, cutoff=0.6)
        if close and close[0] in missing:
            hint = f" Did you mean {close[0]!r} instead of {name!r}?"
            break
    found = ", ".join(repr(n) for n in names) or "none"
    return InputError(
        f"{path}: line {line}: missing column {missing} (found {found}).{hint} "
        f"Allowed columns: {ALLOWED_COLUMNS_TEXT}; others are ignored"
    )


def _cell_value(
    path: Path, where: str, column: str, cell: str, bounds: tuple[float, float], unit: str
) -> float:
    text = cell.strip()
    shown = repr(text) if len(text) <= 40 else repr(text[:37]) + "..."
    try:
        value = float(text)
    except ValueError:
        shown = shown if text else "an empty cell"
        raise InputError(
            f"{path}: {where}: column {column!r}: {shown} is not a number; allowed: a decimal number"
        ) from None
    lo, hi = bounds
    if not math.isfinite(value):
        raise InputError(
            f"{path}: {where}: column {column!r}: {shown}; allowed: a finite number {lo:g} to {hi:g} {unit}"
        )
    if not lo <= value <= hi or (column != DISTANCE_COLUMN and 0 < value < SMALLEST_NONZERO):
        zero = f"0 or {SMALLEST_NONZERO:g}" if column != DISTANCE_COLUMN else f"{lo:g}"
        raise InputError(f"{path}: {where}: column {column!r}: {value!r}; allowed: {zero} to {hi:g} {unit}")
    return value


def read_fit_csv(path: str | Path, g: float = PAPER_G_M_S2) -> FitData:
    """Read (distance, mass) pairs from a fit CSV; `force_n` is converted to mass with `g`.

    Raises InputError naming the file, the line and data row, the column and what is allowed.
    """
    p = Path(path)
    text = read_text_file(p, what="a CSV file")

    reader = csv.reader(text.splitlines(keepends=True))
    header: list[str] | None = None
    header_line = 0
    distance_index = mass_index = censored_index = -1
    mass_column = MASS_COLUMN
    distances: list[float] = []
    masses: list[float] = []
    censored: list[bool] = []
    try:
        for row in reader:
            line = reader.line_num
            if not row or all(not cell.strip() for cell in row) or row[0].lstrip().startswith("#"):
                continue
            if header is None:
                header = [cell.strip() for cell in row]
                header_line = line
                duplicates = sorted({n for n in header if n and header.count(n) > 1})
                if duplicates:
                    raise InputError(
                        f"{p}: line {line}: column {duplicates[0]!r} appears twice; allowed: once"
                    )
                if DISTANCE_COLUMN not in header:
                    raise _header_error(p, line, header, repr(DISTANCE_COLUMN))
                has_mass, has_force = MASS_COLUMN in header, FORCE_COLUMN in header
                if has_mass and has_force:
                    raise InputError(
                        f"{p}: line {line}: both 'mass_kg' and 'force_n' columns; allowed: one of them"
                    )
                if not (has_mass or has_force):
                    raise _header_error(p, line, header, f"{MASS_COLUMN!r} or {FORCE_COLUMN!r}")
                mass_column = MASS_COLUMN if has_mass else FORCE_COLUMN
                distance_index = header.index(DISTANCE_COLUMN)
                mass_index = header.index(mass_column)
                censored_index = header.index(CENSORED_COLUMN) if CENSORED_COLUMN in header else -1
                continue
            where = f"data row {len(distances) + 1} (line {line})"
            if len(row) != len(header):
                raise InputError(
                    f"{p}: {where}: {len(row)} fields but the header (line {header_line}) has {len(header)}; "
                    "allowed: one field per column"
                )
            distance = _cell_value(p, where, DISTANCE_COLUMN, row[distance_index], DISTANCE_RANGE_M, "m")
            if mass_column == MASS_COLUMN:
                value = _cell_value(p, where, mass_column, row[mass_index], MASS_RANGE_KG, "kg")
            else:
                value = _cell_value(p, where, mass_column, row[mass_index], FORCE_RANGE_N, "N")
            flag = False
            if censored_index >= 0:
                cell = row[censored_index].strip().lower()
                if cell not in CENSORED_VALUES:
                    shown = repr(cell) if len(cell) <= 40 else repr(cell[:37]) + "..."
                    raise InputError(
                        f"{p}: {where}: column {CENSORED_COLUMN!r}: {shown}; allowed: 0, 1, true, false "
                        "or empty (1/true: no slip up to this load)"
                    )
                flag = CENSORED_VALUES[cell]
            distances.append(distance)
            masses.append(value if mass_column == MASS_COLUMN else value / g)
            censored.append(flag)
    except csv.Error as exc:
        raise InputError(f"{p}: line {reader.line_num}: malformed CSV ({exc})") from None

    if header is None:
        raise InputError(
            f"{p}: the file is empty; allowed: a header line naming {ALLOWED_COLUMNS_TEXT}, "
            "then one row per trial"
        )
    if len(distances) < 2:
        raise InputError(
            f"{p}: {len(distances)} data row(s) after the header; allowed: at least 2 (distance, mass) rows"
        )
    slips = censored.count(False)
    if slips < 2:
        raise InputError(
            f"{p}: {slips} slip row(s) (rows not marked censored); allowed: at least 2 for a fit"
        )
    return FitData(tuple(distances), tuple(masses), mass_column, tuple(censored))


def _bounds(pair: tuple[float, float]) -> str:
    """Bounds as shown: never below 0 (`nonnegative_bounds`), a clipped end marked with *."""
    lo, hi = nonnegative_bounds(pair)
    return f"[{lo:.6g}{'*' if lo != pair[0] else ''}, {hi:.6g}{'*' if hi != pair[1] else ''}]"


def _clipped_note(fit: FitSummary) -> list[str]:
    """The footnote for bounds shown as 0 because the t interval reaches below it."""
    if fit.k_ci[0] >= 0.0:
        return []
    return [
        f"* the {100 * fit.level:g} % t interval on k reaches below 0 (its lower end {fit.k_ci[0]:.6g} "
        f"kg·m, dfe = {fit.dfe}); k, the capacity and mu_s·delta0 cannot be negative, so 0 is shown: "
        "the data do not bound them away from 0 (more slips narrow the interval)"
    ]


def _fit_rows(fit: FitSummary, t_value: float | None) -> list[list[Any]]:
    r2 = "undefined (all masses equal)" if math.isnan(fit.r2) else f"{fit.r2:.6g}"
    if fit.r2 < 0.0:
        r2 += " (degenerate)"
    rows: list[list[Any]] = [
        ["k", fit.k, _bounds(fit.k_ci), "kg·m"],
        ["SSE", fit.sse, "", "kg²"],
        ["SST", fit.sst, "", "kg²"],
        ["R²", r2, "", ""],
        ["RMSE", fit.rmse, "", "kg"],
        ["dfe", fit.dfe, "", ""],
        ["se(k)", fit.se, "", "kg·m"],
    ]
    if t_value is not None:
        rows.append([f"t({(1 + fit.level) / 2:g}, {fit.dfe})", t_value, "", ""])
    rows += [
        ["mu_s·delta0", fit.mu_delta0_pa, _bounds(fit.mu_delta0_ci_pa), "Pa"],
        ["capacity N_max", fit.capacity_nm, _bounds(fit.capacity_ci_nm), "N·m"],
    ]
    return rows


def human_report(path: Path, data: FitData, summary: EstimateSummary, g: float) -> str:
    """The readable summary `rig fit` prints without --json: the chosen estimator's fit and the paper's."""
    fit, est, paper = summary.fit, summary.estimate, summary.paper
    level_pct = f"{100 * fit.level:g} %"
    source = "" if data.mass_source == MASS_COLUMN else f" (masses from force_n / g, g = {g:g} m/s²)"
    censored = f", {est.n_censored} censored (no slip: lower bounds)" if any(data.censored) else ""
    header = ["quantity", "value", f"{level_pct} bounds", "unit"]
    lines = [f"{path}: {len(data.masses_kg)} points{censored}{source}; fit m = k / l", ""]
    degenerate = degenerate_fit(data, summary)
    lines += [f"DEGENERATE FIT: {reason}" for reason in degenerate] + ([""] if degenerate else [])
    if est.estimator != "paper":
        lines += [
            f"estimator {est.estimator}: scatter sd(m)² = a² + (b·m)², a = {est.scatter_a_kg:.4g} kg, "
            f"b = {est.scatter_b:.4g}; model: {est.scatter_model}",
        ]
        diagnostic = est.diagnostic
        if diagnostic is not None:
            verdict = "supported" if diagnostic.decided else "likelier, but the data cannot tell"
            lines.append(
                f"  likelihood ratio vs mixed: additive {diagnostic.lr_additive:.3g} "
                f"(p = {diagnostic.p_additive:.3g}), multiplicative {diagnostic.lr_multiplicative:.3g} "
                f"(p = {diagnostic.p_multiplicative:.3g}) -> {diagnostic.supported} ({verdict})"
            )
        if est.n_censored:
            lines.append(f"  {est.n_censored} censored point(s) enter as lower bounds (Tobit likelihood)")
        lines += ["", format_table(header, _fit_rows(fit, None)), *_clipped_note(fit), ""]
        lines.append("the paper's fit (least squares through the origin, MATLAB cftool conventions):")
    else:
        lines.append("estimator paper: least squares through the origin (MATLAB cftool conventions)")
    if est.note:
        lines.append(f"  {est.note}")
    if paper is not None:
        t_value = (paper.k_ci[1] - paper.k) / paper.se if paper.se > 0 else math.nan
        lines += ["", format_table(header, _fit_rows(paper, t_value)), *_clipped_note(paper)]
    lines += [
        "",
        f"constant c = {fit.c:.8g} ({fit.constant}); R = {fit.radius_m:g} m; g = {g:g} m/s²",
        "capacity = k·g does not depend on c; mu_s·delta0 = k·g / (c·R³) does.",
    ]
    return "\n".join(lines)


def degenerate_fit(data: FitData, summary: EstimateSummary) -> tuple[str, ...]:
    """Why the fit says nothing about m = k/l (empty: a sound fit), judged on the paper's fit of the slips."""
    slips = [d for d, censored in zip(data.distances_m, data.censored or (), strict=False) if not censored]
    return degenerate_reasons(slips or data.distances_m, summary.paper or summary.fit)


def run(args: argparse.Namespace) -> int:
    """Read the CSV, fit, print the table or the JSON object."""
    radius, constant, level, g = _options(args)
    try:
        estimator = check_estimator(args.estimator)
    except ValueError:
        raise InputError(f"--estimator {args.estimator!r}: allowed: {', '.join(ESTIMATOR_NAMES)}") from None
    path = Path(args.data)
    data = read_fit_csv(path, g=g)
    try:
        summary = summarize_estimate(
            estimator,
            data.distances_m,
            data.masses_kg,
            data.censored or None,
            level=level,
            radius_m=radius,
            constant=constant,
            g=g,
        )
    except ValueError as exc:  # every input was checked above; this keeps any residue one line
        raise InputError(f"{path}: {exc}") from None
    if args.json:
        emit_json({**summary.as_json(), "degenerate": list(degenerate_fit(data, summary))})
    else:
        print(human_report(path, data, summary, g))
    return 0
