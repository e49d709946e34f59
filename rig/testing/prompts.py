"""A wrapper for any `Operator`: the prompts a run made, and a Ctrl-C at a chosen trial's prompt.

Test doubles only (`rig.testing` is imported by no rig module). It wraps the session's own operator
(the simulated person, who may act on a prompt) rather than replacing it:

    operator = RecordingOperator(rig.session.operator, interrupt_at_trial=2)
    session = dataclasses.replace(rig.session, operator=operator)
    ...
    operator.prompts  # [(1, "place the hook ..."), (2, "...")]

At the prompt of trial `interrupt_at_trial` it raises KeyboardInterrupt instead of passing the prompt
on: the operator pressed Ctrl-C rather than confirming, so nothing the prompt asks for happens.
`on_prompt`, if given, is called with the trial (None outside a trial) before the prompt is passed on.
"""

from __future__ import annotations

from collections.abc import Callable

from rig.hw.session import Operator, OperatorRequest
from rig.inputs.protocol import TrialPlan


class RecordingOperator:
    """Records each prompt, then passes it on to `inner` (or raises KeyboardInterrupt at the chosen trial)."""

    def __init__(
        self,
        inner: Operator,
        *,
        interrupt_at_trial: int | None = None,
        on_prompt: Callable[[TrialPlan | None], None] | None = None,
    ) -> None:
        self.inner = inner
        self.interrupt_at_trial = interrupt_at_trial
        self.on_prompt = on_prompt
        self.prompts: list[tuple[int | None, str]] = []  # (trial id or None, text)

    def confirm(self, request: OperatorRequest, keep_alive: Callable[[], None]) -> None:
        """Record the request; Ctrl-C at the trial to interrupt, else the wrapped operator confirms."""
        trial = request.trial
        trial_id = trial.trial_id if trial is not None else None
        self.prompts.append((trial_id, request.text))
        if self.on_prompt is not None:
            self.on_prompt(trial)
        if trial_id is not None and trial_id == self.interrupt_at_trial:
            raise KeyboardInterrupt
        self.inner.confirm(request, keep_alive)
