"""The sections of `rig check`, in the order they run: each a function of the context returning rows.

A section is `(name, function)`; `rig check --only NAME...` runs the named ones. The order matters:
the ports first (nothing opened), then the servos (the bus connected), the load cell and the line
(the cell listened to once), the limits (no device), and the jog last (only with `--move`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from rig.preflight.check_context import CheckContext
from rig.preflight.jog import jog_rows
from rig.preflight.line import slack_rows
from rig.preflight.loadcell import loadcell_rows
from rig.preflight.port_checks import port_rows
from rig.preflight.servos import servo_rows
from rig.preflight.tension_limits import limit_rows
from rig.preflight.verdicts import CheckRow

SectionFn = Callable[[CheckContext], list[CheckRow]]

SECTIONS: tuple[tuple[str, SectionFn], ...] = (
    ("ports", port_rows),
    ("servos", servo_rows),
    ("loadcell", loadcell_rows),
    ("line", slack_rows),
    ("limits", limit_rows),
    ("move", jog_rows),
)


def section_names() -> tuple[str, ...]:
    """The sections' names, in running order."""
    return tuple(name for name, _ in SECTIONS)


def run_sections(ctx: CheckContext, only: Sequence[str] = ()) -> list[CheckRow]:
    """Run the chosen sections (all when `only` is empty) in order; the devices are closed after."""
    rows: list[CheckRow] = []
    try:
        for name, section in SECTIONS:
            if not only or name in only:
                rows += section(ctx)
    finally:
        ctx.close()
    return rows
