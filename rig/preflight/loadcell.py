"""The load-cell diagnostic: listen to the cell through the real driver, then one row per finding.

Like Klipper's `LOAD_CELL_DIAGNOSTIC` (it collects samples and reports the sample rate, the noise,
the unique values and whether the converter saturated), but for the rig's serial cells and with a
verdict and a fix on every row (`rig.preflight.verdicts.CheckRow`): whether the cell answers, its
banner, its measured rate and jitter, its noise in counts and newtons, how many distinct values it
sent, saturation, gaps and damaged lines, and how far its clock runs from the host's (ppm).

`listen` opens the cell (its `open()`: a board that resets on DTR gets the driver's boot grace),
waits for the first sample, then collects for `window_s` and closes it. `diagnose` turns what was
heard into rows; it needs nothing but that record, so the pre-flight command can call it from its
own `loadcell` section. The cell should be at rest (nothing on the line) for the noise rows.

Thresholds are stated with each row; they are the project's choices, not from a datasheet, except
the HX711's output code limits (0x800000 and 0x7FFFFF: saturation).
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

from rig.errors import NotConnectedError, StaleDataError
from rig.hw.loadcell.driver import LoadCellStats, SerialLoadCell, baud_and_firmware
from rig.hw.loadcell.formats import InfoLine
from rig.hw.seams import Clock, LoadCellSample
from rig.inputs.rig_config import RigConfig, StaleTimeoutFit
from rig.preflight.check_context import CheckContext
from rig.preflight.verdicts import CheckRow, Verdict
from rig.vocabulary import LoadCellFormatName

SECTION = "loadcell"
DEFAULT_WINDOW_S = 10.0
POLL_EVERY_S = 0.01
MIN_SAMPLES = 10
RATE_TOLERANCE = 0.10  # measured against configured rate (an HX711's oscillator is nominal only)
JITTER_WARN, JITTER_FAIL = 0.10, 0.50  # RMS interval deviation, as a fraction of the period
NOISE_WARN_N, NOISE_FAIL_N = 0.05, 0.5  # RMS at rest (the simulated default cell: 5 mN)
STUCK_UNIQUE_VALUES = 3  # at most this many distinct values in a window: a stuck converter
DAMAGE_WARN = 0.001  # damaged or missing lines, as a fraction of the lines expected
SKEW_WARN_PPM, SKEW_FAIL_PPM = 1000.0, 20_000.0  # a crystal is ~50 ppm, a ceramic resonator 0.5 %
SKEW_SEGMENTS = 4  # the clock's rate from the lower envelope: minima of this many equal stretches
ADC24_LIMITS = (-(1 << 23), (1 << 23) - 1)  # an HX711's saturated codes (rig-lc1 sends them raw)
_NOT_ANSWERING_FIX = (
    "see docs/hardware-loadcell.md; an Arduino resets when its port opens: raise loadcell.boot_grace_s "
    "if it needs longer"
)


@dataclass(frozen=True)
class CellListening:
    """What the diagnostic heard: the samples, when each poll returned them, and the driver's counts."""

    port: str
    format: LoadCellFormatName
    window_s: float
    samples: tuple[LoadCellSample, ...] = ()
    receipt_ns: tuple[int, ...] = ()  # host monotonic time of the poll that returned each sample
    stats: LoadCellStats | None = None
    banner: InfoLine | None = None
    info: tuple[InfoLine, ...] = ()
    factor_n_per_count: float | None = None  # the calibration's, if any
    configured_rate_hz: float | None = None
    baud: int = 0
    failure: str = ""  # why listening stopped early (stale data, port lost), if it did
    first_sample_after_s: float | None = None  # from open() to the first sample (a DTR reset shows here)


def listen(
    load_cell: SerialLoadCell,
    clock: Clock,
    window_s: float = DEFAULT_WINDOW_S,
    configured_rate_hz: float | None = None,
    *,
    already_open: bool = False,
) -> CellListening:
    """Open the cell, wait for its first sample (its boot grace), collect `window_s`, close it.

    `configured_rate_hz` is the rate the rig config states (default: the driver's). With
    `already_open` the cell is neither opened nor closed here (the pre-flight command keeps it open
    for the sections after this one).
    """
    samples: list[LoadCellSample] = []
    receipts: list[int] = []
    failure = ""
    first_after_s: float | None = None
    if not already_open:
        load_cell.open()
    opened_ns = clock.monotonic_ns()
    end_ns: int | None = None
    try:
        while end_ns is None or clock.monotonic_ns() < end_ns:
            clock.sleep(POLL_EVERY_S)
            got = load_cell.poll()
            if got:
                now_ns = clock.monotonic_ns()
                if end_ns is None:
                    first_after_s = (now_ns - opened_ns) / 1e9
                    end_ns = now_ns + round(window_s * 1e9)
                samples += got
                receipts += [now_ns] * len(got)
    except (StaleDataError, NotConnectedError) as exc:
        failure = str(exc)
    finally:
        stats = load_cell.stats()
        info = load_cell.info_lines()
        banner = load_cell.banner
        if not already_open:
            load_cell.close()
    calibration = load_cell.calibration
    return CellListening(
        port=load_cell.port,
        format=LoadCellFormatName(load_cell.format_name),
        window_s=window_s,
        samples=tuple(samples),
        receipt_ns=tuple(receipts),
        stats=stats,
        banner=banner,
        info=tuple(info),
        factor_n_per_count=calibration.factor_n_per_count if calibration is not None else None,
        configured_rate_hz=configured_rate_hz if configured_rate_hz is not None else load_cell.rate_hz,
        baud=load_cell.baud,
        failure=failure,
        first_sample_after_s=first_after_s,
    )


def diagnose(heard: CellListening) -> list[CheckRow]:
    """One row per finding, each with its verdict and what to do."""
    samples = heard.samples
    if len(samples) < MIN_SAMPLES:
        reason = heard.failure or f"{len(samples)} samples in {heard.window_s:g} s"
        return [
            CheckRow(
                SECTION,
                "load cell answers",
                Verdict.FAIL,
                f"{heard.port}: {reason}",
                f"check the cable and that {heard.port} is the cell's port (`rig ports`), that loadcell.baud "
                f"({baud_and_firmware(heard.baud, heard.format)}) and loadcell.format ({heard.format}) "
                "match its firmware; " + _NOT_ANSWERING_FIX,
            )
        ]
    rows = [_answers(heard)]
    rows += _banner(heard)
    rate_hz, rate_rows = _rate(heard)
    rows += rate_rows
    rows.append(_jitter(heard, rate_hz))
    rows += _noise(heard)
    rows.append(_unique(heard))
    rows.append(_saturation(heard))
    rows.append(_gaps(heard, rate_hz))
    rows.append(_skew(heard))
    return rows


def _answers(heard: CellListening) -> CheckRow:
    first = heard.first_sample_after_s
    after = f", first sample {first:.2f} s after opening" if first is not None else ""
    verdict, fix = Verdict.PASS, ""
    if heard.failure:
        verdict, fix = Verdict.FAIL, f"the cell stopped during the window ({heard.failure}); check the cable"
    return CheckRow(
        SECTION,
        "load cell answers",
        verdict,
        f"{heard.port}: {len(heard.samples)} samples in {heard.window_s:g} s ({heard.format}){after}",
        fix,
    )


def _banner(heard: CellListening) -> list[CheckRow]:
    if heard.format != LoadCellFormatName.RIG_LC1:  # the one format with information lines
        return [CheckRow(SECTION, "banner", Verdict.PASS, f"not sent by the {heard.format} format")]
    rows: list[CheckRow] = []
    if heard.banner is not None:
        rows.append(CheckRow(SECTION, "banner", Verdict.PASS, f"#{heard.banner.text}"))
    else:
        rows.append(
            CheckRow(
                SECTION,
                "banner",
                Verdict.WARN,
                "no #BOOT banner since the port opened",
                "the board did not restart on open (no DTR reset, or `stty -hupcl`), or its firmware is "
                "not firmware/rig_hx711: press its reset button during a check to see the banner",
            )
        )
    restarts = heard.stats.restarts if heard.stats is not None else 0
    if restarts:
        rows.append(
            CheckRow(
                SECTION,
                "restarts",
                Verdict.FAIL,
                f"the device restarted {restarts} time(s) during the window",
                "a brown-out or a loose cable: check the board's supply and the USB cable",
            )
        )
    return rows


def _rate(heard: CellListening) -> tuple[float, list[CheckRow]]:
    rate_hz = measured_rate_hz(heard.samples)
    configured = heard.configured_rate_hz
    if configured is None:
        return rate_hz, [
            CheckRow(
                SECTION,
                "rate",
                Verdict.WARN,
                f"{rate_hz:.2f} samples/s measured; no rate configured",
                f"set loadcell.rate_hz: {rate_hz:.4g} (it sets the stale timeout and is checked against the "
                "baud rate)",
            )
        ]
    off = abs(rate_hz - configured) / configured
    ok = off <= RATE_TOLERANCE
    return rate_hz, [
        CheckRow(
            SECTION,
            "rate",
            Verdict.PASS if ok else Verdict.FAIL,
            f"{rate_hz:.2f} samples/s measured, {configured:g} configured ({off:.1%} off)",
            ""
            if ok
            else "set loadcell.rate_hz to what the cell sends, or the cell's rate (an HX711's RATE pin: "
            "low 10/s, high 80/s)",
        )
    ]


def measured_rate_hz(samples: Sequence[LoadCellSample]) -> float:
    """Samples per second: from the device's clock when the format has one, else from the host's stamps."""
    device = _device_times_s(samples)
    if device is not None:
        span_s = device[-1] - device[0]
    else:
        span_s = (samples[-1].time_ns - samples[0].time_ns) / 1e9
    return (len(samples) - 1) / span_s if span_s > 0 else math.inf


def _device_times_s(samples: Sequence[LoadCellSample]) -> list[float] | None:
    """The device clock's times in seconds, unwrapped; None when the format has no device clock."""
    if any(s.device_time_us is None for s in samples):
        return None
    times: list[float] = []
    wraps = 0
    last = None
    for s in samples:
        t = s.device_time_us
        assert t is not None
        if last is not None and t < last and last - t > 1 << 31:
            wraps += 1
        last = t
        times.append((t + wraps * (1 << 32)) / 1e6)
    return times


def _jitter(heard: CellListening, rate_hz: float) -> CheckRow:
    device = _device_times_s(heard.samples)
    if device is not None:
        times, where = device, "device clock"
    else:
        times, where = [s.time_ns / 1e9 for s in heard.samples], "host receipt"
    intervals = [b - a for a, b in itertools.pairwise(times)]
    period = 1.0 / rate_hz
    spread = statistics.pstdev(intervals) / period if len(intervals) > 1 else 0.0
    verdict = Verdict.PASS if spread < JITTER_WARN else Verdict.WARN if spread < JITTER_FAIL else Verdict.FAIL
    fix = ""
    if verdict is not Verdict.PASS:
        fix = (
            "the firmware skips conversions (it must poll DOUT at least at the rate) or the host reads "
            "late (a USB hub, the FTDI latency timer: docs/hardware.md)"
            if device is not None
            else "stamped on receipt: a polled or unstamped cell's jitter is the host's; use rig-lc1 for "
            "device timestamps"
        )
    return CheckRow(
        SECTION,
        "jitter",
        verdict,
        f"interval RMS deviation {spread:.1%} of the {period * 1e3:.2f} ms period ({where})",
        fix,
    )


def _detrended_rms(values: Sequence[float]) -> float:
    """RMS about the least-squares line through the values (a slow drift is not noise)."""
    n = len(values)
    mean_x = (n - 1) / 2
    mean_y = sum(values) / n
    sxx = sum((i - mean_x) ** 2 for i in range(n))
    slope = sum((i - mean_x) * (v - mean_y) for i, v in enumerate(values)) / sxx if sxx else 0.0
    residuals = [v - mean_y - slope * (i - mean_x) for i, v in enumerate(values)]
    return math.sqrt(sum(r * r for r in residuals) / n)


def _noise(heard: CellListening) -> list[CheckRow]:
    raws = [float(s.raw) for s in heard.samples]
    counts = _detrended_rms(raws)
    unit = "µN (a value-unit count)" if heard.format == LoadCellFormatName.VALUE_UNIT else "counts"
    rows = [CheckRow(SECTION, "noise (counts)", Verdict.PASS, f"{counts:.1f} {unit} RMS at rest")]
    factor = heard.factor_n_per_count
    if factor is None:
        rows.append(
            CheckRow(
                SECTION,
                "noise (newtons)",
                Verdict.WARN,
                "no calibration: the noise in newtons is unknown",
                "calibrate the cell (`rig calibrate --rig CONFIG`) and set loadcell.calibration",
            )
        )
        return rows
    noise_n = counts * abs(factor)
    verdict = (
        Verdict.PASS if noise_n < NOISE_WARN_N else Verdict.WARN if noise_n < NOISE_FAIL_N else Verdict.FAIL
    )
    rows.append(
        CheckRow(
            SECTION,
            "noise (newtons)",
            verdict,
            f"{noise_n * 1e3:.2f} mN RMS at rest",
            ""
            if verdict is Verdict.PASS
            else "with nothing on the line: shield and shorten the bridge wires, keep them off the servo "
            "power, check the excitation supply; a slower rate (HX711 10/s) halves the noise",
        )
    )
    return rows


def _unique(heard: CellListening) -> CheckRow:
    distinct = len({s.raw for s in heard.samples})
    measured = f"{distinct} distinct values in {len(heard.samples)} samples"
    if heard.format != LoadCellFormatName.RIG_LC1:  # a display's last digit is often coarser than its noise
        return CheckRow(
            SECTION,
            "unique values",
            Verdict.PASS,
            f"{measured} (a displayed reading: constant at rest is normal; load the line to see it move)",
        )
    stuck = distinct <= STUCK_UNIQUE_VALUES and len(heard.samples) >= MIN_SAMPLES
    return CheckRow(
        SECTION,
        "unique values",
        Verdict.FAIL if stuck else Verdict.PASS,
        measured,
        "the converter repeats itself: a DOUT/SCK wiring fault, a powered-down HX711, or firmware "
        "sending a stale value"
        if stuck
        else "",
    )


def _saturation(heard: CellListening) -> CheckRow:
    low, high = ADC24_LIMITS
    if heard.format == LoadCellFormatName.RIG_LC1:
        saturated = sum(1 for s in heard.samples if s.raw <= low or s.raw >= high)
    else:
        saturated = heard.stats.overload_lines if heard.stats is not None else 0
    return CheckRow(
        SECTION,
        "saturation",
        Verdict.FAIL if saturated else Verdict.PASS,
        f"{saturated} of {len(heard.samples)} samples at the converter's limits or flagged overload",
        "the input is out of range: check the bridge wiring (E+, E-, A+, A-; a swapped pair reads "
        "full scale), the cell's capacity and the gain"
        if saturated
        else "",
    )


def _gaps(heard: CellListening, rate_hz: float) -> CheckRow:
    stats = heard.stats
    if stats is None:
        return CheckRow(SECTION, "gaps and damaged lines", Verdict.WARN, "no counts from the driver")
    damaged = stats.corrupt_lines + stats.checksum_failures + stats.missing_samples + stats.samples_dropped
    expected = max(1, len(heard.samples) + damaged)
    fraction = damaged / expected
    verdict = Verdict.PASS if damaged == 0 else Verdict.WARN if fraction <= DAMAGE_WARN else Verdict.FAIL
    return CheckRow(
        SECTION,
        "gaps and damaged lines",
        verdict,
        f"{stats.missing_samples} missing in {stats.sequence_gaps} gaps, {stats.corrupt_lines} garbled, "
        f"{stats.checksum_failures} bad checksums, {stats.bytes_discarded} bytes discarded",
        ""
        if verdict is Verdict.PASS
        else f"lines lost or damaged at {heard.baud} baud: a shorter or better USB cable, no hub; a baud the "
        "board divides exactly (250000 or 500000 on a 16 MHz AVR); or a lower rate",
    )


def clock_skew_ppm(samples: Sequence[LoadCellSample], receipt_ns: Sequence[int]) -> float | None:
    """The device clock's rate error (positive: slow), from the lower envelope of receipt - device time.

    The samples are split into `SKEW_SEGMENTS` equal stretches; the slope between the first and the
    last stretch's minimum of `receipt - device time` is the rate error. None without a device clock
    or with too few samples.
    """
    device = _device_times_s(samples)
    if device is None or len(samples) < 4 * SKEW_SEGMENTS:
        return None
    observed = [r / 1e9 - d for r, d in zip(receipt_ns, device, strict=True)]
    size = len(samples) // SKEW_SEGMENTS
    lows = []
    for k in (0, SKEW_SEGMENTS - 1):
        part = range(k * size, (k + 1) * size)
        i = min(part, key=observed.__getitem__)
        lows.append((device[i], observed[i]))
    (d0, o0), (d1, o1) = lows
    return (o1 - o0) / (d1 - d0) * 1e6 if d1 > d0 else None


def _skew(heard: CellListening) -> CheckRow:
    skew = clock_skew_ppm(heard.samples, heard.receipt_ns)
    if skew is None:
        return CheckRow(
            SECTION, "clock skew", Verdict.PASS, f"no device clock in {heard.format}: stamped on receipt"
        )
    size = abs(skew)
    verdict = Verdict.PASS if size < SKEW_WARN_PPM else Verdict.WARN if size < SKEW_FAIL_PPM else Verdict.FAIL
    fixes = {
        Verdict.PASS: "",
        Verdict.WARN: "a ceramic resonator: the driver tracks the rate (stamps stay right), but its UART "
        "baud is off by as much; a board with a crystal is better",
        Verdict.FAIL: "the device clock is far off (wrong F_CPU, or the internal oscillator): its baud rate "
        "is off by as much and lines will garble",
    }
    slow = "slow" if skew > 0 else "fast"
    return CheckRow(
        SECTION,
        "clock skew",
        verdict,
        f"{size:.0f} ppm {slow} against the host (lower envelope over {heard.window_s:g} s)",
        fixes[verdict],
    )


def loadcell_rows(ctx: CheckContext) -> list[CheckRow]:
    """The pre-flight section `loadcell`: the diagnostic over the listening window, and the stale timeout.

    The cell stays open for the sections after this one; they read the samples heard here
    (`CheckContext.cell_samples`).
    """
    cell = ctx.load_cell()
    port = ctx.config.loadcell.port
    if cell is None or not isinstance(cell, SerialLoadCell):
        reason = ctx.cell_failure or "the rig's load cell is not a serial cell"
        return [CheckRow(SECTION, "load cell answers", Verdict.FAIL, f"{port}: {reason}", _NOT_ANSWERING_FIX)]
    heard = listen(
        cell, ctx.clock, ctx.options.loadcell_window_s, ctx.config.loadcell.rate_hz, already_open=True
    )
    if len(heard.samples) < MIN_SAMPLES:
        ctx.cell_failure = heard.failure or f"{len(heard.samples)} samples in {heard.window_s:g} s"
    else:
        ctx.listened = list(heard.samples)
        ctx.listened_s = heard.window_s
    rows = diagnose(heard)
    if len(heard.samples) >= MIN_SAMPLES:
        rows.append(_stale_timeout(ctx.config, measured_rate_hz(heard.samples)))
    return rows


def _stale_timeout(config: RigConfig, rate_hz: float) -> CheckRow:
    fit = StaleTimeoutFit(config.limits.stale_timeout_s, rate_hz)
    return CheckRow(
        SECTION,
        "stale timeout holds the sample period",
        Verdict.PASS if fit.ok else Verdict.FAIL,
        fit.describe(),
        "" if fit.ok else fit.fix(),
    )
