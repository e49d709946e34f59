"""Pre-flight section `loadcell` (basic): the cell answers, and at the rate the rig expects.

A minimal diagnostic (the full one, with noise, saturation, gaps and clock skew, is its own
module): the cell is listened to for `CheckOptions.loadcell_window_s`; the measured sample rate is
compared with the configured one where the config states one (the simulated rig's
`simulation.loadcell_rate_hz`), and always with the stale timeout, which must hold several sample
periods or a run stops on stale data between two healthy samples.
"""

from __future__ import annotations

from rig.preflight.context import CheckContext
from rig.preflight.verdicts import CheckRow, Verdict

SECTION = "loadcell"
# The stale timeout must hold at least this many sample periods.
SAMPLE_PERIODS_PER_STALE_TIMEOUT = 3
# The measured rate may differ from the configured one by this fraction (a crystal-less HX711 is
# nominal only; its datasheet gives 10 or 80 SPS from the internal oscillator).
RATE_TOLERANCE = 0.10


def loadcell_rows(ctx: CheckContext) -> list[CheckRow]:
    """Listen to the cell; rows for whether it answers and its rate."""
    config = ctx.config
    port = config.loadcell.port
    samples = ctx.cell_samples()
    if samples is None or len(samples) < 2:
        reason = ctx.cell_failure or f"{len(samples or [])} samples in {ctx.options.loadcell_window_s:g} s"
        fix = (
            f"check the cable and that {port} is the cell's port (`rig ports`), that loadcell.baud "
            f"({config.loadcell.baud}) and loadcell.format ({config.loadcell.format}) match its firmware "
            "(docs/hardware-loadcell.md); an Arduino restarts when its port opens and sends nothing "
            "for about 1.5 s"
        )
        return [CheckRow(SECTION, "load cell answers", Verdict.FAIL, f"{port}: {reason}", fix)]
    window_s = ctx.listened_s
    rate_hz = len(samples) / window_s
    rows = [
        CheckRow(
            SECTION,
            "load cell answers",
            Verdict.PASS,
            f"{port}: {len(samples)} samples in {window_s:.2f} s ({config.loadcell.format})",
        )
    ]
    expected_hz = config.simulation.loadcell_rate_hz if config.simulation is not None else None
    if expected_hz is not None:
        off = abs(rate_hz - expected_hz) / expected_hz
        rows.append(
            CheckRow(
                SECTION,
                "load cell rate",
                Verdict.PASS if off <= RATE_TOLERANCE else Verdict.WARN,
                f"{rate_hz:.1f} Hz measured, {expected_hz:g} Hz configured",
                "" if off <= RATE_TOLERANCE else "check the cell's firmware rate (its RATE pin on an HX711)",
            )
        )
    stale_s = config.limits.stale_timeout_s
    periods = stale_s * rate_hz
    ok = periods >= SAMPLE_PERIODS_PER_STALE_TIMEOUT
    needed_s = SAMPLE_PERIODS_PER_STALE_TIMEOUT / rate_hz
    rows.append(
        CheckRow(
            SECTION,
            "stale timeout holds the sample period",
            Verdict.PASS if ok else Verdict.FAIL,
            f"limits.stale_timeout_s {stale_s:g} s = {periods:.1f} sample periods at {rate_hz:.1f} Hz",
            ""
            if ok
            else f"raise limits.stale_timeout_s to at least {needed_s:.2f} s, or run the cell faster",
        )
    )
    return rows
