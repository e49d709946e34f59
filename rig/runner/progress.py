"""Progress for people: a bar with ETA and a live table on a TTY, plain lines otherwise, nothing with --json.

Each display is a run sink (`rig.runner.sinks`) that shows the run's start, its trials and its
one-line messages and ignores the rest. All output goes to stderr, so stdout stays clean for
`--json` and pipes.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from rig.records import Estimate, TrialOutcome, TrialResult
from rig.runner.sinks import NullSink, RunSink

# `--json`: the progress display says nothing.
SilentProgress = NullSink


def _result_line(r: TrialResult) -> str:
    parts = [f"trial {r.trial_id:>3}", f"{r.outcome:<11}"]
    if r.distance_m is not None:
        parts.append(f"l={r.distance_m:.3f} m")
    if r.configuration_index is not None:
        parts.append(f"config {r.configuration_index}")
    if r.peak_force_n is not None and r.slip_mass_kg is not None:
        bound = "" if r.slipped else ">= "  # no slip, or not the joint's: the capacity is above it
        parts.append(f"peak {bound}{r.peak_force_n:.2f} N ({r.slip_mass_kg:.3f} kg)")
    if r.outcome == TrialOutcome.OTHER_JOINT:
        parts.append(f"joint {r.slipped_joint} moved")
    if r.reason is not None:
        parts.append(f"({r.reason})")
    if r.predicted_mass_kg is not None:
        parts.append(f"predicted {r.predicted_mass_kg:.3f} kg")
    if r.percentage_error is not None:
        parts.append(f"error {r.percentage_error:.1f} %")
    return "  ".join(parts)


class PlainProgress(NullSink):
    """Not a TTY: one line per event, with elapsed wall time and an ETA."""

    def __init__(self, stream: Any = None) -> None:
        self.stream = stream or sys.stderr
        self.total = 0
        self.done = 0
        self.started_at = time.monotonic()
        self.done_at_start = 0

    def _print(self, text: str) -> None:
        print(text, file=self.stream, flush=True)

    def start(self, run_id: str, total: int, done: int) -> None:
        self.total, self.done, self.done_at_start = total, done, done
        self.started_at = time.monotonic()
        self._print(f"run {run_id}: {total} trials, {done} already done")

    def trial_finished(self, result: TrialResult, estimate: Estimate) -> None:
        self.done += 1
        elapsed = time.monotonic() - self.started_at
        rate = (self.done - self.done_at_start) / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else 0.0
        self._print(
            f"[{self.done}/{self.total} eta {eta:5.0f} s] {_result_line(result)}  | {estimate.text()}"
        )

    def message(self, text: str) -> None:
        self._print(text)


class LiveProgress(NullSink):
    """A TTY: a progress bar with ETA above a table of the latest trials and the current estimate."""

    def __init__(self, rows_shown: int = 12) -> None:
        self.console = Console(stderr=True)
        self.progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("eta"),
            TimeRemainingColumn(),
            console=self.console,
        )
        self.rows: list[TrialResult] = []
        self.rows_shown = rows_shown
        self.estimate_text = "no estimate yet"
        self.task: Any = None
        self.live: Live | None = None

    def _render(self) -> Group:
        table = Table(expand=False, title=self.estimate_text, title_justify="left")
        for header in ("trial", "outcome", "distance / config", "peak N", "mass kg", "pred kg", "err %"):
            table.add_column(header, justify="right")
        for r in self.rows[-self.rows_shown :]:
            where = f"{r.distance_m:.3f} m" if r.distance_m is not None else f"config {r.configuration_index}"
            table.add_row(
                str(r.trial_id),
                str(r.outcome),
                where,
                _fmt(r.peak_force_n, ".2f"),
                _fmt(r.slip_mass_kg, ".3f"),
                _fmt(r.predicted_mass_kg, ".3f"),
                _fmt(r.percentage_error, ".1f"),
            )
        return Group(self.progress, table)

    def start(self, run_id: str, total: int, done: int) -> None:
        self.task = self.progress.add_task(f"run {run_id}", total=total, completed=done)
        self.live = Live(self._render(), console=self.console, refresh_per_second=4, transient=False)
        self.live.start()

    def trial_started(self, trial_id: int, description: str) -> None:
        self.progress.update(self.task, description=f"trial {trial_id}: {description}")

    def trial_finished(self, result: TrialResult, estimate: Estimate) -> None:
        self.rows.append(result)
        self.estimate_text = estimate.text()
        self.progress.advance(self.task)
        if self.live is not None:
            self.live.update(self._render())

    def message(self, text: str) -> None:
        self.console.print(text)

    def stop(self) -> None:
        if self.live is not None:
            self.live.stop()
            self.live = None


def _fmt(value: Any, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def make_progress(json_output: bool) -> RunSink:
    """Silent for --json, live on a terminal, plain lines otherwise."""
    if json_output:
        return SilentProgress()
    if sys.stderr.isatty():
        return LiveProgress()
    return PlainProgress()
