"""A wrapper for any device seam (a `ServoBus`, a `LoadCell`) that raises chosen errors, for fault tests.

Test doubles only (`rig.testing` is imported by no rig module). Shaped like
`rig.testing.recording.RecordingServoBus`: it wraps the object-level simulated devices
(`rig.sim.object_devices`) rather than re-implementing a bus or a cell, so that a test chooses
when a device fails while the device otherwise behaves as the simulator's does:

    servos = ErrorInjector(rig.devices.bus)
    servos.raise_on_call("write_goal_positions", CommunicationError("no reply"), nth=3)
    servos.raise_while(CommunicationError("cable pulled"))  # every call, until `stop_raising()`
    cell = ErrorInjector(rig.session.load_cell)
    cell.raise_while(StaleDataError("no valid sample for 0.2 s"), methods={"poll"})

A failing call does not reach the wrapped device (the bytes never arrived). Each raise is a fresh
exception of the given one's type and arguments, so that notes the runner adds to one do not pile
up on the next. Every other attribute is the wrapped device's.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any


@dataclass
class _OnCall:
    """Raise `error` on call number `nth` of `method`, counted from when it was armed."""

    method: str
    error: BaseException
    nth: int
    calls_before: int


class ErrorInjector:
    """Passes every call on to `inner`, unless an injected error is due; see the module docstring."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.calls: Counter[str] = Counter()  # calls of each public method, the failed ones included
        self._on_call: list[_OnCall] = []
        self._raising: BaseException | None = None
        self._raising_methods: frozenset[str] | None = None  # None: every method

    def raise_on_call(self, method: str, error: BaseException, *, nth: int = 1) -> None:
        """Raise `error` on the `nth` call of `method` from now on (once)."""
        if not callable(getattr(self.inner, method, None)) or method.startswith("_"):
            raise ValueError(f"{method!r}: not a public method of {type(self.inner).__name__}")
        if nth < 1:
            raise ValueError(f"nth = {nth}; allowed: >= 1")
        self._on_call.append(_OnCall(method, error, nth, self.calls[method]))

    def raise_while(self, error: BaseException, *, methods: Iterable[str] | None = None) -> None:
        """Raise `error` on every call of `methods` (None: of every method) until `stop_raising()`."""
        self._raising = error
        self._raising_methods = None if methods is None else frozenset(methods)

    def stop_raising(self) -> None:
        """End `raise_while`: calls reach the device again."""
        self._raising = None
        self._raising_methods = None

    def __getattr__(self, name: str) -> Any:
        attribute = getattr(self.inner, name)
        if name.startswith("_") or not callable(attribute):
            return attribute
        method: Callable[..., Any] = attribute

        def injected(*args: Any, **kwargs: Any) -> Any:
            self.calls[name] += 1
            error = self._due(name)
            if error is not None:
                raise type(error)(*error.args)
            return method(*args, **kwargs)

        return injected

    def _due(self, name: str) -> BaseException | None:
        """The error this call of `name` raises, if any (a due one-shot error is used up)."""
        for armed in self._on_call:
            if armed.method == name and self.calls[name] - armed.calls_before == armed.nth:
                self._on_call.remove(armed)
                return armed.error
        if self._raising is not None and (self._raising_methods is None or name in self._raising_methods):
            return self._raising
        return None
