"""What a run needs from a rig, real or simulated: devices, clock, operator, bending fixture.

`RigSession` bundles the seams (`rig.hw.seams`) plus two rig-level roles the protocol steps use:
the `Operator` (prompts a person, or auto-confirms in simulation, where the simulated operator
also does the physical action, such as moving the hook) and the `BendingFixture` (turns a planar
configuration into bender-servo goals, or asks the operator to bend the link by hand).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from rig.errors import InputError
from rig.hw.seams import Clock, ConfigurationSource, LoadCell, ServoBus
from rig.protocol import TrialPlan


class Operator(Protocol):
    """Whoever confirms operator steps."""

    def confirm(self, text: str, trial: TrialPlan | None) -> None:
        """Show `text` and return once the step is done (raise KeyboardInterrupt to abort)."""
        ...


class BendingFixture(Protocol):
    """Sets the link's configuration before a validation trial and resets it after."""

    def bend_goals(self, joint_angles_rad: tuple[float, ...]) -> dict[int, float]:
        """Bender-servo goal positions [rad] for a configuration ({} when bending is manual)."""
        ...

    def home_goals(self) -> dict[int, float]:
        """Bender-servo goal positions [rad] of the straight (reset) link."""
        ...


class ConsoleOperator:
    """A person at the terminal: prompts on stderr, waits for Enter on stdin."""

    def confirm(self, text: str, trial: TrialPlan | None) -> None:
        """Prompt and wait for Enter; no terminal is an error (nobody could answer)."""
        if not sys.stdin or not sys.stdin.isatty():
            raise InputError(f"operator step needs a person at a terminal: {text}")
        print(f"\n>>> {text}  [Enter to continue, Ctrl-C to abort] ", end="", file=sys.stderr, flush=True)
        sys.stdin.readline()


class ManualBending:
    """No bender servos: the configuration is set by hand after a prompt."""

    def bend_goals(self, joint_angles_rad: tuple[float, ...]) -> dict[int, float]:
        """No servo goals: the runner falls back to an operator prompt."""
        return {}

    def home_goals(self) -> dict[int, float]:
        """No servo goals."""
        return {}


@dataclass
class RigSession:
    """A connected-or-connectable rig as the runner sees it."""

    kind: str  # "simulated" or "hardware"
    clock: Clock
    servos: ServoBus  # e.g. rig.hw.dxl.bus.DynamixelServoBus
    load_cell: LoadCell
    operator: Operator
    fixture: BendingFixture
    configuration: ConfigurationSource | None
    winch_id: int
    roles: dict[int, str]
    begin_trial: Callable[[TrialPlan], None] = field(default=lambda trial: None)
    truth: Callable[..., dict[str, Any]] | None = None  # truth(detail=False): simulation only
    attachments: list[tuple[str, str, bytes]] = field(default_factory=list)  # (name, media type, data)
    close: Callable[[], None] = field(default=lambda: None)
    sim_devices: dict[str, Any] | None = (
        None  # simulation only: emulators and world, for tests and fault injection
    )
