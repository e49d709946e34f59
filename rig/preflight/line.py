"""Pre-flight section `line`: the line is slack now (the load cell reads its calibrated zero).

The same tolerance as a run's check at connect and each trial's tare (`limits.zero_tolerance_n`):
a line loaded now (a stop that could not release it, a hook left on) would be refused by the run
anyway; here it is found before anything is connected for a run.
"""

from __future__ import annotations

import math
import statistics

from rig.preflight.check_context import CheckContext
from rig.preflight.verdicts import CheckRow, Verdict

SECTION = "line"


def slack_rows(ctx: CheckContext) -> list[CheckRow]:
    """One row: the mean tension over the listening window against the zero tolerance."""
    check = "line slack (load cell at its zero)"
    tolerance_n = ctx.config.limits.zero_tolerance_n
    samples = ctx.cell_samples()
    if samples is None or not samples:
        measured = f"no samples ({ctx.cell_failure or 'the cell sent nothing'})"
        return [CheckRow(SECTION, check, Verdict.FAIL, measured, "see the loadcell section")]
    if not ctx.calibrated:
        fix = (
            "calibrate the cell (`rig calibrate --rig CONFIG ...`) and name the file in loadcell.calibration"
        )
        problem = ctx.devices.calibration_problem if ctx.devices is not None else ""
        measured = f"no calibration ({problem}): the reading is not in newtons"
        return [CheckRow(SECTION, check, Verdict.FAIL, measured, fix)]
    forces = [s.force_n for s in samples if math.isfinite(s.force_n)]
    mean_n = statistics.fmean(forces)
    measured = f"{mean_n:+.2f} N over {len(forces)} samples (limits.zero_tolerance_n {tolerance_n:g} N)"
    if abs(mean_n) <= tolerance_n:
        return [CheckRow(SECTION, check, Verdict.PASS, measured)]
    fix = (
        "slacken the line by hand (torque off: the winch turns freely), or if it is slack, the cell's zero "
        "moved: recalibrate with `rig calibrate`; a run refuses to start on a loaded line"
    )
    return [CheckRow(SECTION, check, Verdict.FAIL, measured, fix)]
