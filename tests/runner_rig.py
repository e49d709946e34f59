"""The runner tests' rig: the object-level simulated rig of a prepared run, its seams wrapped.

`runner_rig(prepared)` builds what `rig run --devices object` would run on (`open_simulated_rig`
at the object level: the run's config, seed and invocation) and wraps the session's seams (rig/testing/):

* servos: `RecordingServoBus` over an `ErrorInjector` over the object-level bus, so that the calls
  that failed are recorded too;
* load cell: a `_WatchedLoadCell` (calls an action at the first sample at or above a tension) over an
  `ErrorInjector` over the object-level cell;
* operator: `RecordingOperator` over the simulated person (prompts, a Ctrl-C at a chosen trial).

Expectations come from the world (`rig.world`: its truth, line and winch), never from the fake
physics the runner tests once had. `EXACT_RIG` is the built-in simulated rig without noise: every
trial's slip is sudden, at the specimen's capacity over the distance exactly.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import pytest

from rig.hw.seams import LoadCellSample
from rig.hw.session import RigSession
from rig.rigs import open_simulated_rig
from rig.runner.execute import PreparedRun, RunReport, execute_run
from rig.runner.progress import SilentProgress
from rig.sim.kinds import DeviceLevel
from rig.sim.physics.world import SimWorld
from rig.sim.simulated_rig import SimulatedRig
from rig.testing.injected_errors import ErrorInjector
from rig.testing.prompts import RecordingOperator
from rig.testing.recording import RecordingServoBus

# The built-in simulated rig with every noise level at 0: no capacity scatter, no load-cell noise.
EXACT_RIG = "extends: simulated\nname: exact\nsimulation: {noise_scale: 0}\n"


class _WatchedLoadCell:
    """Passes the cell's calls on; `poll` calls `action(sample)` once, at the first sample >= `force_n`."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self._watch: tuple[float, Callable[[LoadCellSample], None]] | None = None

    def watch(self, force_n: float, action: Callable[[LoadCellSample], None]) -> None:
        self._watch = (force_n, action)

    def poll(self) -> list[LoadCellSample]:
        samples: list[LoadCellSample] = self.inner.poll()
        if self._watch is not None:
            force_n, action = self._watch
            reached = next((s for s in samples if s.force_n >= force_n), None)
            if reached is not None:
                self._watch = None
                action(reached)
        return samples

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


@dataclass
class RunnerRig:
    """The object-level simulated rig with wrapped seams, and the session built from them."""

    sim: SimulatedRig
    session: RigSession
    servos: RecordingServoBus
    bus_errors: ErrorInjector
    cell_errors: ErrorInjector
    operator: RecordingOperator
    watched_cell: _WatchedLoadCell

    @property
    def world(self) -> SimWorld:
        """The simulated world behind the devices."""
        return self.sim.world

    @property
    def winch_rad(self) -> float:
        """The winch's shaft angle now."""
        return self.sim.devices.bus.servo(self.session.winch_id).present_position_rad

    def when_tension_reaches(self, force_n: float, action: Callable[[LoadCellSample], None]) -> None:
        """Call `action(sample)` once, on the first polled sample with at least `force_n` on the line."""
        self.watched_cell.watch(force_n, action)


def runner_rig(prepared: PreparedRun, *, interrupt_at_trial: int | None = None) -> RunnerRig:
    """The object-level simulated rig `prepared` runs on, wrapped; Ctrl-C at `interrupt_at_trial`'s prompt."""
    sim = open_simulated_rig(prepared, devices=DeviceLevel.OBJECT)
    bus_errors = ErrorInjector(sim.devices.bus)
    servos = RecordingServoBus(bus_errors)  # a ServoBus by delegation
    cell_errors = ErrorInjector(sim.session.load_cell)
    watched = _WatchedLoadCell(cell_errors)
    operator = RecordingOperator(sim.session.operator, interrupt_at_trial=interrupt_at_trial)
    session = dataclasses.replace(sim.session, servos=servos, load_cell=watched, operator=operator)
    return RunnerRig(sim, session, servos, bus_errors, cell_errors, operator, watched)


def execute_on(prepared: PreparedRun, rig: RunnerRig, progress: SilentProgress | None = None) -> RunReport:
    """`execute_run` of `prepared` on the rig's wrapped session (its truth beside it)."""
    return execute_run(
        prepared, dataclasses.replace(rig.sim, session=rig.session), progress or SilentProgress()
    )


def assert_released_then_torque_off(rig: RunnerRig) -> None:
    """Once the shutdown began: the winch sent back to slack line, then torque off; it ends there, slack.

    The object-level bus runs the runner's release before it turns the torque off (as the driver
    does), so a release goal recorded after `shutdown` and a winch found at it, torque off, on a slack
    line, is a release that came first.
    """
    names = rig.servos.call_names()
    assert "shutdown" in names, names
    start = names.index("shutdown")
    winch = rig.session.winch_id
    calls = [c for c in rig.servos.calls if c.name != "read_states"]
    goals = [
        c.args["goals_rad"][winch]
        for c in calls[start + 1 :]
        if c.name == "write_goal_positions" and winch in c.args["goals_rad"]
    ]
    assert goals, names[start:]
    # Back at the release goal within the runner's position tolerance (0.02 rad), torque off, and the
    # line slack there: at most 1 N on it (the world's own tension, not the cell's reading).
    assert rig.winch_rad == pytest.approx(goals[-1], abs=0.02)
    line = rig.world.line
    assert goals[-1] <= rig.world.taut_winch_angle_rad() + 1.0 / (line.stiffness_n_per_m * line.drum_radius_m)
    assert not any(servo.torque_enabled for servo in rig.sim.devices.bus.servos)
    assert rig.world.tension_n < 1.0
    assert rig.cell_errors.calls["close"] >= 1
