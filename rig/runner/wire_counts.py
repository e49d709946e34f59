"""Per-trial counts of what the device wires delivered and lost (servo bus and load-cell line).

Each comes from its driver's cumulative counters, when it keeps them. `TrialWireCounter(session)`
takes both before a trial; `finish(trial_id)` gives the trial's differences as the
`/rig/trial/links` record, which the runner logs and `rig replay` shows. Given the control loop's
tick counter (`ticks`), the record also says how many of the trial's ticks started late.
"""

from __future__ import annotations

from collections.abc import Callable

from rig.hw.dxl.transport import BusStats
from rig.hw.seams import BusStatsSource, LineStatsSource, LoadCellLineStats
from rig.hw.session import RigSession
from rig.records import ControlTickStats, TrialWireStats


class TrialWireCounter:
    """The link counters at the start of a trial (see the module docstring)."""

    def __init__(self, session: RigSession, ticks: Callable[[], ControlTickStats] | None = None) -> None:
        self._session = session
        self._ticks = ticks
        if ticks is not None:
            ticks()  # start the trial's count
        self._bus_before = self._bus()
        self._lines_before = self._lines()

    def _bus(self) -> BusStats | None:
        servos = self._session.servos
        return servos.stats if isinstance(servos, BusStatsSource) else None

    def _lines(self) -> LoadCellLineStats | None:
        cell = self._session.load_cell
        return cell.line_stats() if isinstance(cell, LineStatsSource) else None

    def finish(self, trial_id: int) -> TrialWireStats:
        """What the wires did since this counter was made."""
        bus, lines = self._bus(), self._lines()
        return TrialWireStats(
            trial_id=trial_id,
            bus=None if bus is None or self._bus_before is None else bus.since(self._bus_before),
            loadcell=None if lines is None or self._lines_before is None else lines.since(self._lines_before),
            control=None if self._ticks is None else self._ticks(),
        )
