"""The session contract: what a run needs from a rig, real or simulated (devices, clock, operator, fixture).

`RigSession` bundles the seams (`rig.hw.seams`) plus two rig-level roles the protocol steps use:
the `Operator` (the person at the rig, asked by an `OperatorRequest` to follow a prompt or to bend or
straighten the link by hand) and the `BendingFixture` (turns a planar configuration into
bender-servo goals, or asks the operator to bend the link by hand). Every field is something a
hardware rig has; what only a simulation knows (its hidden truth) stays with the composition.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

from rig.hw.bending import BendStage
from rig.hw.seams import Clock, ConfigurationSource, LoadCell, ServoBus
from rig.inputs.protocol import TrialPlan
from rig.vocabulary import ConfigurationSourceKind, RigKind, ServoRole


class OperatorTask(StrEnum):
    """What the runner asks of the person at the rig."""

    FOLLOW_PROMPT = "follow_prompt"  # do what the protocol's prompt step says (e.g. hang the hook)
    BEND_LINK = "bend_link"  # bend the link by hand to `OperatorRequest.joint_angles_rad`
    STRAIGHTEN_LINK = "straighten_link"  # straighten the link by hand (the reset)


@dataclass(frozen=True)
class OperatorRequest:
    """One request to the operator: the task, the text to show and the trial it belongs to."""

    task: OperatorTask
    text: str
    trial: TrialPlan | None
    joint_angles_rad: tuple[float, ...] | None = None  # BEND_LINK: the configuration [rad per joint]


class Operator(Protocol):
    """Whoever confirms operator steps."""

    def confirm(self, request: OperatorRequest, keep_alive: Callable[[], None]) -> None:
        """Show `request.text` and return once the task is done (raise KeyboardInterrupt to abort).

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
    attachments: list[tuple[str, str, bytes]] = field(default_factory=list)  # (name, media type, data)
    configuration_kind: ConfigurationSourceKind | None = None  # the source behind `configuration`
