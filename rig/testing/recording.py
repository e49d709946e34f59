"""A recording wrapper for any `ServoBus`: the calls a run made, in order, with their arguments.

Test doubles only (`rig.testing` is imported by no rig module). Wrap the object-level simulated
servos (`rig.sim.object_devices.ObjectServoBus`, driven by the same world as the byte-level rig)
rather than re-implementing a bus, so that a test checks what the runner asked of the servos while
the servos behave as the simulator's do:

    rig = simulated_rig(config, devices=DeviceLevel.OBJECT)
    servos = RecordingServoBus(rig.devices.bus)
    session = dataclasses.replace(rig.session, servos=servos)
    ...
    servos.calls_to("set_torque")  # [ServoCall("set_torque", {"servo_ids": [2], "enabled": False}), ...]

The seam's methods are not restated here: each call to a method that `rig.hw.seams.ServoBus`
declares is recorded under that method's parameter names (bound with its signature) and passed on;
every other attribute is the wrapped bus's.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any, NamedTuple

from rig.hw.seams import ServoBus

# The seam's methods, with their signatures (the Protocol's own declarations).
_SEAM_SIGNATURES: dict[str, inspect.Signature] = {
    name: inspect.signature(member)
    for name, member in vars(ServoBus).items()
    if not name.startswith("_") and inspect.isfunction(member)
}
_READS = frozenset({"read_states"})


class ServoCall(NamedTuple):
    """One recorded call: the seam method's name and its arguments by parameter name."""

    name: str
    args: dict[str, Any]


class RecordingServoBus:
    """Passes every call on to `inner`; records those to the `ServoBus` seam's methods in `calls`."""

    def __init__(self, inner: ServoBus) -> None:
        self.inner = inner
        self.calls: list[ServoCall] = []

    def __getattr__(self, name: str) -> Any:
        attribute = getattr(self.inner, name)
        signature = _SEAM_SIGNATURES.get(name)
        if signature is None or not callable(attribute):
            return attribute

        def recorded(*args: Any, **kwargs: Any) -> Any:
            bound = signature.bind(self.inner, *args, **kwargs)
            bound.apply_defaults()
            self.calls.append(ServoCall(name, dict(list(bound.arguments.items())[1:])))
            method: Callable[..., Any] = attribute
            return method(*args, **kwargs)

        return recorded

    def calls_to(self, name: str) -> list[ServoCall]:
        """The recorded calls of one method, in order."""
        return [c for c in self.calls if c.name == name]

    def call_names(self, *, reads: bool = False) -> list[str]:
        """The names of the recorded calls, in order (state reads left out unless `reads`)."""
        return [c.name for c in self.calls if reads or c.name not in _READS]
