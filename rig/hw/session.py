"""The session contract: what a run needs from a rig, real or simulated (devices, clock, operator, fixture).

`RigSession` bundles the seams (`rig.hw.seams`) plus two rig-level roles the protocol steps use:
the `Operator` (prompts a person, or auto-confirms in simulation, where the simulated operator
also does the physical action, such as moving the hook) and the `BendingFixture` (turns a planar
configuration into bender-servo goals, or asks the operator to bend the link by hand).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

from rig.hw.bending import BendStage
from rig.hw.seams import Clock, ConfigurationSource, LoadCell, ServoBus
from rig.protocol import TrialPlan
from rig.vocabulary import ConfigurationSourceKind, RigKind, ServoRole

if TYPE_CHECKING:
    from rig.sim.truth import RunTruth


class GroundTruth(Protocol):
    """What a simulated rig knows and a real one cannot: the hidden truth the estimates should find."""

    def snapshot(self) -> RunTruth:
        """The truth now: the world's (with every trial's hidden draws and slips) and the rig's state."""
        ...


class Operator(Protocol):
    """Whoever confirms operator steps."""

    def confirm(self, text: str, trial: TrialPlan | None, keep_alive: Callable[[], None]) -> None:
        """Show `text` and return once the step is done (raise KeyboardInterrupt to abort).

        While waiting, call `keep_alive()` over and over: each call is one control period of the
        runner (the rig is read and logged, the interlocks are checked, and the servos keep hearing
        the host, so their Bus Watchdog does not trip during a long prompt).
        """
        ...


class BendingFixture(Protocol):
    """Sets the link's configuration before a validation trial and resets it after (rig/hw/bending.py)."""

    def bend_stages(
        self,
        target_rad: Sequence[float],
        present_rad: Sequence[float],
        positions_rad: Mapping[int, float],
        *,
        tolerance_rad: float = 0.0,
        correcting: bool = False,
    ) -> list[BendStage]:
        """The forks' moves, in order, toward `target_rad` ([] when bending is manual)."""
        ...

    def begin_stage(self, stage: BendStage) -> None:
        """A fork closes on its component before it moves."""
        ...

    def end_stage(self, stage: BendStage) -> None:
        """The fork has arrived: it holds its component."""
        ...

    def end_bend(self) -> None:
        """Every fork opens: the link is free for the trial."""
        ...

    def home_goals(self) -> dict[int, float]:
        """Bender-servo goal positions [rad] of the reset (the link straightened, forks home)."""
        ...


@dataclass
class RigSession:
    """A connected-or-connectable rig as the runner sees it."""

    kind: RigKind
    clock: Clock
    servos: ServoBus  # e.g. rig.hw.dxl.bus.DynamixelServoBus
    load_cell: LoadCell
    operator: Operator
    fixture: BendingFixture
    configuration: ConfigurationSource | None
    winch_id: int
    roles: dict[int, ServoRole]
    begin_trial: Callable[[TrialPlan], None] = field(default=lambda trial: None)
    truth: GroundTruth | None = None  # simulation only: what the rig should find
    attachments: list[tuple[str, str, bytes]] = field(default_factory=list)  # (name, media type, data)
    close: Callable[[], None] = field(default=lambda: None)
    log_limit_bytes: int | None = None  # the most the run's log file may hold (writes beyond fail)
    configuration_kind: ConfigurationSourceKind | None = None  # the source behind `configuration`
    # Bending by hand (no forks), after the operator's prompt: what the simulated person does.
    hand_bend: Callable[[tuple[float, ...]], None] = field(default=lambda angles: None)
    hand_straighten: Callable[[], None] = field(default=lambda: None)
