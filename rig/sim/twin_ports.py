"""The twin's two ports as a person at the bench can upset them: an adapter pulled out, or one that hangs.

Each device of the twin (`rig sim rig`, rig/sim/twin.py) is served on a pty symlinked at its config
port, by a thread of its own. A port is in one of three conditions:

* served: plugged in and passing bytes both ways;
* frozen: plugged in but hung, as a USB-serial adapter that stops passing data: the port stays
  open and the host's writes are accepted, but nothing reaches the device and nothing comes back.
  What passed neither way meanwhile is lost when it thaws (the host's bytes are discarded, and the
  cell's lines of the frozen time are never sent). The devices behind it go on in the world: the
  servos hear nothing, so their Bus Watchdog trips;
* unplugged: the adapter pulled out: the pty is closed and its link removed, so the host's open
  port fails (EIO, as pyserial reports a vanished device) and the path is gone until it is plugged
  back, as a new pty at the same path (as a `/dev/serial/by-id` name comes back on re-enumeration).

The person (the twin's console, rig/sim/twin_console.py, from its own thread) asks for a condition,
for good or for some seconds (`PortRequests`); the twin's main thread brings each `ServedPort` to
what is asked on every tick. A config's `simulation.faults` load-cell `disconnect` pulls the cell's
cable out for its window the same way. How real adapters hang or re-enumerate is not verified on
hardware.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from rig.sim.pty_port import PtyPort, Stop


class TwinDevice(StrEnum):
    """The twin's devices, each behind its own port."""

    SERVOS = "servos"
    LOADCELL = "loadcell"


class PortCondition(StrEnum):
    """What a twin's port does (module docstring)."""

    SERVED = "served"
    FROZEN = "frozen"
    UNPLUGGED = "unplugged"


class PortAction(StrEnum):
    """What the person does to a port, and the condition it wants from which one."""

    UNPLUG = "unplug"
    REPLUG = "replug"
    FREEZE = "freeze"
    THAW = "thaw"


# action -> (the conditions it applies to, the condition it leaves)
_ACTIONS: dict[PortAction, tuple[frozenset[PortCondition], PortCondition]] = {
    PortAction.UNPLUG: (frozenset({PortCondition.SERVED, PortCondition.FROZEN}), PortCondition.UNPLUGGED),
    PortAction.REPLUG: (frozenset({PortCondition.UNPLUGGED}), PortCondition.SERVED),
    PortAction.FREEZE: (frozenset({PortCondition.SERVED}), PortCondition.FROZEN),
    PortAction.THAW: (frozenset({PortCondition.FROZEN}), PortCondition.SERVED),
}


@dataclass
class _Request:
    condition: PortCondition = PortCondition.SERVED
    until_ns: int | None = None  # back to served at this monotonic time (None: until asked)


class PortRequests:
    """The condition the person asked for each port; thread-safe (the console asks, the twin reads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._requests = {device: _Request() for device in TwinDevice}
        self._refused: dict[TwinDevice, str] = {}

    def refuse(self, device: TwinDevice, why: str) -> None:
        """Answer every action on `device` with `why` (a port the twin does not serve itself)."""
        with self._lock:
            self._refused[device] = why

    def ask(self, action: PortAction, device: TwinDevice, now_ns: int, seconds: float | None = None) -> str:
        """Do `action` to `device`'s port (for `seconds`, then back to served); what was done, one line."""
        applies_to, leaves = _ACTIONS[action]
        with self._lock:
            if device in self._refused:
                return f"{action} {device}: {self._refused[device]}"
            request = self._requests[device]
            present = self._condition(request, now_ns)
            if present not in applies_to:
                return f"{action} {device}: the port is {present}; allowed: {_allowed_actions(present)}"
            request.condition = leaves
            request.until_ns = None if seconds is None else now_ns + round(seconds * 1e9)
        for_how_long = "" if seconds is None else f" for {seconds:g} s"
        return f"{action} {device}{for_how_long}: ok"

    def wanted(self, device: TwinDevice, now_ns: int) -> PortCondition:
        """The condition asked for `device` at `now_ns` (a timed one that has run out is over)."""
        with self._lock:
            return self._condition(self._requests[device], now_ns)

    @staticmethod
    def _condition(request: _Request, now_ns: int) -> PortCondition:
        if request.until_ns is not None and now_ns >= request.until_ns:
            request.condition, request.until_ns = PortCondition.SERVED, None
        return request.condition


def _allowed_actions(condition: PortCondition) -> str:
    return ", ".join(str(a) for a, (applies_to, _) in _ACTIONS.items() if condition in applies_to)


class ServedPort:
    """One device's pty at its config path and the thread serving it, in the condition it is brought to.

    Only the twin's main thread calls `settle` and `close`. `open_pty` makes the pty and its link;
    `serve(pty, stop)` serves it until `stop.stopped`; `resume(pty)` drops what a frozen or
    unplugged port did not pass before serving starts again; `start(target)` runs the serving in a
    thread (the twin's, which hands an error to the main thread).
    """

    def __init__(
        self,
        open_pty: Callable[[], PtyPort],
        serve: Callable[[PtyPort, Stop], object],
        resume: Callable[[PtyPort], None],
        start: Callable[[Callable[[], object]], threading.Thread],
    ) -> None:
        self._open_pty = open_pty
        self._serve = serve
        self._resume = resume
        self._start = start
        self.pty: PtyPort | None = open_pty()
        self.path = self.pty.link_path  # where the config's port is, plugged in or not
        self.condition = PortCondition.FROZEN  # open, not yet served
        self._stop = Stop()
        self._thread: threading.Thread | None = None

    def settle(self, wanted: PortCondition) -> bool:
        """Bring the port to `wanted`; whether it changed."""
        if wanted is self.condition:
            return False
        self._stop_serving()
        if wanted is PortCondition.UNPLUGGED:
            assert self.pty is not None
            self.pty.close()
            self.pty = None
        else:
            if self.pty is None:  # plugged back: a new pty at the same path
                self.pty = self._open_pty()
            if wanted is PortCondition.SERVED:
                self._resume(self.pty)
                self._serve_now(self.pty)
        self.condition = wanted
        return True

    def close(self) -> None:
        """Stop serving and remove the pty and its link."""
        self._stop_serving()
        if self.pty is not None:
            self.pty.close()
            self.pty = None

    def _serve_now(self, pty: PtyPort) -> None:
        stop = self._stop = Stop()
        self._thread = self._start(lambda: self._serve(pty, stop))

    def _stop_serving(self) -> None:
        self._stop.stopped = True
        if self._thread is not None:
            self._thread.join()
            self._thread = None
