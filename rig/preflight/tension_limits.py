"""Pre-flight section `limits`: the tension limits in their order, from software to the hardware ratings.

protocol ceiling <= rig ceiling (`limits.force_ceiling_n`) < the winch's stall tension (its current
limit on its drum) <= 1.25 x the rig ceiling < the load cell's rated capacity. Every check here is
the one the rest of the rig applies, called rather than restated: the cap is
`rig.inputs.rig_config.check_tension_cap`, a protocol's checks are `rig.runner.limits.limit_checks`
(what `rig run --dry-run` prints); only the load cell's capacity is new.
"""

from __future__ import annotations

from rig.errors import ConfigError
from rig.inputs.rig_config import RigConfig, check_tension_cap
from rig.inputs.servo_ratings import STALL_TENSION_CEILING_RATIO
from rig.preflight.check_context import CheckContext
from rig.preflight.verdicts import CheckRow, Verdict
from rig.runner.limits import limit_checks

SECTION = "limits"


def limit_rows(ctx: CheckContext) -> list[CheckRow]:
    """The cap, the cell's capacity, and each given protocol's checks against this rig."""
    config = ctx.config
    rows = [tension_cap_row(config), *capacity_rows(config)]
    for protocol in ctx.options.protocols:
        for check in limit_checks(protocol, config):
            rows.append(
                CheckRow(
                    SECTION,
                    f"{protocol.name}: {check.name}",
                    Verdict.PASS if check.ok else Verdict.FAIL,
                    f"{check.value} (limit {check.limit})",
                    "" if check.ok else f"change {protocol.source} or the rig config so that this holds",
                )
            )
    return rows


def tension_cap_row(config: RigConfig) -> CheckRow:
    """The winch's stall tension at its current limit within 1.25 x the force ceiling."""
    stall_n = config.winch_stall_tension_n
    ceiling_n = config.limits.force_ceiling_n
    measured = (
        f"{config.limits.winch_current_limit_a:g} A stalls at {stall_n:.1f} N; "
        f"{STALL_TENSION_CEILING_RATIO:g} x force_ceiling_n = {STALL_TENSION_CEILING_RATIO * ceiling_n:.1f} N"
    )
    check = "winch stall tension <= 1.25 x force ceiling"
    try:
        check_tension_cap(config)
    except ConfigError as exc:
        return CheckRow(SECTION, check, Verdict.FAIL, measured, str(exc).rsplit("; ", 1)[-1])
    return CheckRow(SECTION, check, Verdict.PASS, measured)


def capacity_rows(config: RigConfig) -> list[CheckRow]:
    """The force ceiling and the winch's stall tension below the load cell's rated capacity."""
    capacity_n = config.loadcell.capacity_n
    if capacity_n is None:
        fix = "set loadcell.capacity_n to the cell's rated capacity (its datasheet) so that this is checked"
        return [CheckRow(SECTION, "load cell capacity", Verdict.WARN, "loadcell.capacity_n not set", fix)]
    rows = []
    for check, tension_n in (
        ("force ceiling < load cell capacity", config.limits.force_ceiling_n),
        ("winch stall tension < load cell capacity", config.winch_stall_tension_n),
    ):
        ok = tension_n < capacity_n
        rows.append(
            CheckRow(
                SECTION,
                check,
                Verdict.PASS if ok else Verdict.FAIL,
                f"{tension_n:.1f} N vs {capacity_n:g} N",
                "" if ok else "use a cell rated above the winch's stall tension, or lower the current limit",
            )
        )
    return rows
