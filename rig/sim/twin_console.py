"""The twin's console: what the person at the twin does by hand, typed on its stdin (`rig sim rig`).

`hang KG` hangs a reference mass in the line at the load cell, `unhang` takes it off: the cell then
reads KG x standard gravity (9.80665 m/s², `rig calibrate`'s default `--g`) on top of the line's
tension, as when a known mass hangs from the line over the pulley with the link unhooked. With it
`rig calibrate --rig CONFIG --reference-kg KG` is rehearsed against the twin. `trial N` makes the
hand set up the protocol's trial N now and go on from it, as the person does who follows the run's
prompt when the run repeats a trial (rig/sim/twin_hand.py).

The person can also upset a device's port (rig/sim/twin_ports.py): `unplug servos|loadcell`
pulls its USB adapter out (the host's open port fails, the path is gone) and `replug` puts it
back; `freeze servos|loadcell` hangs the adapter (the port stays open, nothing passes either way)
and `thaw` frees it. `unplug` and `freeze` take an optional duration in seconds, after which the
port is served again by itself. `status` prints one line: the line's tension, the servos whose
torque is on, and each port's condition. A line that is not a command gets one line of help; the
console never stops the twin.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Protocol, TextIO

from model.gravity import STANDARD_GRAVITY_M_S2
from rig.sim.twin_ports import PortAction, TwinDevice

MAX_REFERENCE_KG = 1000.0
MAX_PORT_FAULT_S = 3600.0  # the longest timed unplug or freeze
HELP = (
    "commands: `hang KG` (a reference mass in the line, 0-1000 kg), `unhang`, `trial N` (set up trial N), "
    "`unplug|replug|freeze|thaw servos|loadcell [SECONDS]` (a port's adapter pulled out or hung; "
    "SECONDS: for so long), `status` (tension, torque, ports)"
)


class DeviceControls(Protocol):
    """What the console does to the twin's devices."""

    def act(self, action: PortAction, device: TwinDevice, seconds: float | None = None) -> str:
        """Do `action` to `device`'s port (for `seconds`); what was done, one line."""
        ...

    def status(self) -> str:
        """The line's tension, the servos' torque and the ports' conditions, one line."""
        ...


@dataclass
class ReferenceLoad:
    """The tension a mass hung by hand adds to what the load cell reads [N] (read from the cell's thread)."""

    tension_n: float = 0.0
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def hang(self, mass_kg: float) -> None:
        """Hang `mass_kg` in the line (replacing any mass hung before)."""
        with self.lock:
            self.tension_n = mass_kg * STANDARD_GRAVITY_M_S2

    def read_n(self) -> float:
        """The tension the hung mass adds now."""
        with self.lock:
            return self.tension_n


def run_console(
    lines: Iterable[str],
    load: ReferenceLoad,
    out: TextIO,
    set_up_trial: Callable[[int], str] | None = None,
    devices: DeviceControls | None = None,
) -> None:
    """Obey each typed line until the input ends.

    `set_up_trial(N)`: what `trial N` does; `devices`: what the port commands and `status` act on.
    """
    for line in lines:
        words = line.split()
        if not words:
            continue
        match words:
            case ["hang", mass]:
                try:
                    mass_kg = float(mass)
                except ValueError:
                    mass_kg = math.nan
                if not (math.isfinite(mass_kg) and 0 <= mass_kg <= MAX_REFERENCE_KG):
                    print(
                        f"hang {mass}: allowed: a mass in kg from 0 to {MAX_REFERENCE_KG:g}",
                        file=out,
                        flush=True,
                    )
                    continue
                load.hang(mass_kg)
                print(f"hanging {mass_kg:g} kg: {load.read_n():.3f} N in the line", file=out, flush=True)
            case ["trial", number] if set_up_trial is not None:
                try:
                    print(set_up_trial(int(number)), file=out, flush=True)
                except ValueError as exc:  # not a number, or no such trial
                    allowed = str(exc) if str(exc).startswith("allowed") else "allowed: a trial number"
                    print(f"trial {number}: {allowed}", file=out, flush=True)
            case [action, device, *seconds] if devices is not None and action in set(PortAction):
                print(_port_command(devices, PortAction(action), device, seconds), file=out, flush=True)
            case ["status"] if devices is not None:
                print(devices.status(), file=out, flush=True)
            case ["unhang"]:
                load.hang(0.0)
                print("the line is free of the reference mass", file=out, flush=True)
            case _:
                print(f"{line.strip()}: {HELP}", file=out, flush=True)


def _port_command(devices: DeviceControls, action: PortAction, device: str, seconds: list[str]) -> str:
    """`ACTION DEVICE [SECONDS]`, checked; what was done or what is allowed, one line."""
    typed = " ".join([action, device, *seconds])
    if device not in set(TwinDevice):
        return f"{typed}: allowed devices: {', '.join(TwinDevice)}"
    timed = action in (PortAction.UNPLUG, PortAction.FREEZE)
    if not seconds:
        return devices.act(action, TwinDevice(device))
    if not timed or len(seconds) > 1:
        return f"{typed}: allowed: `{action} {device}`{' [SECONDS]' if timed else ''}"
    try:
        duration_s = float(seconds[0])
    except ValueError:
        duration_s = math.nan
    if not (math.isfinite(duration_s) and 0 < duration_s <= MAX_PORT_FAULT_S):
        return f"{typed}: allowed: a duration in seconds above 0, at most {MAX_PORT_FAULT_S:g}"
    return devices.act(action, TwinDevice(device), duration_s)
