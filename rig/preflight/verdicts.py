"""One pre-flight check's outcome as a typed row, and the command's exit code from a list of rows."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import StrEnum

from rig.errors import ExitCode


class Verdict(StrEnum):
    """How a check came out: ready, ready with a caution, or not ready."""

    PASS = "pass"
    WARN = "warn"
    FAIL = "fail"


@dataclass(frozen=True, slots=True)
class CheckRow:
    """One row of `rig check`: what was checked, what was measured, the verdict and the fix.

    `fix` is empty for a pass; for a warn or a fail it says what the operator should do.
    """

    section: str
    check: str
    verdict: Verdict
    measured: str
    fix: str = ""

    def to_json(self) -> dict[str, str]:
        return {
            "section": self.section,
            "check": self.check,
            "verdict": self.verdict.value,
            "measured": self.measured,
            "fix": self.fix,
        }


def exit_code(rows: Iterable[CheckRow]) -> ExitCode:
    """0 when nothing failed (warnings allowed), 1 when any check failed."""
    failed = any(row.verdict is Verdict.FAIL for row in rows)
    return ExitCode.FAULT if failed else ExitCode.OK
