"""The rig's error hierarchy: one root, subclasses that also inherit the matching builtin.

Messages carry what an operator needs to act: units, limits, IDs and retry counts.
"""

from __future__ import annotations

import re
from enum import IntEnum


class RigError(Exception):
    """Root of every error the rig raises on purpose."""


class InputError(RigError, ValueError):
    """Invalid user input (file, field, flag). The CLI exits 2 and nothing was started.

    The message names the file, the field or row, and what is allowed.
    """


class ConfigError(InputError):
    """A rig config or protocol file failed validation."""


class RigTimeoutError(RigError, TimeoutError):
    """A device did not answer within its bounded window."""


class StepTimeoutError(RigTimeoutError):
    """A protocol step (a move, the ramp, the unload) did not finish in the time its motion allows."""


class NotConnectedError(RigError, ConnectionError):
    """A device is missing, unplugged, or was never connected."""


class HandshakeError(NotConnectedError):
    """Connected, but the devices found do not match the configuration.

    `missing_ids`: configured servos that did not answer; `wrong_models`: (servo id, the model name
    found) of those that answered as another model. Both empty when the mismatch is of another kind.
    """

    def __init__(
        self,
        message: str,
        *,
        missing_ids: tuple[int, ...] = (),
        wrong_models: tuple[tuple[int, str], ...] = (),
    ) -> None:
        super().__init__(message)
        self.missing_ids = missing_ids
        self.wrong_models = wrong_models


class CommunicationError(RigError, IOError):
    """Corrupt, short or mismatched replies that survived the allowed retries."""


class HardwareFault(RigError):
    """A device reported a fault (e.g. a latched Dynamixel hardware error)."""


class BusWatchdogTripped(HardwareFault):
    """A servo's Bus Watchdog tripped (the bus was quiet too long); cleared by the driver, the trial void."""


class StaleDataError(RigError, TimeoutError):
    """A stream (e.g. the load cell) delivered no valid sample for longer than allowed."""


class InterlockTripped(RigError):
    """A safety interlock stopped the run; the hardware has been (or is being) made safe."""


class WinchDirectionError(InterlockTripped):
    """A ramp reeled the winch in without the tension rising: the reel direction is likely wrong."""


class ZeroNotVerified(RigError):
    """At connect the load cell read beyond its zero tolerance: the line may be loaded; nothing was reeled."""


class LimitError(RigError, ValueError):
    """A requested motion or load is outside configured limits; checked before anything moves."""


class ExitCode(IntEnum):
    """The process exit codes of every `rig` command (one definition for the CLI and the runner)."""

    OK = 0  # done
    FAULT = 1  # stopped by a fault or an interlock
    INVALID_INPUT = 2  # nothing started; the message names the file and field
    INTERRUPTED = 130  # Ctrl-C or SIGTERM; hardware left safe


_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\ud800-\udfff]")


def one_line(message: str) -> str:
    """`message` with line breaks and other control characters escaped as in Python literals (one line)."""
    return _UNPRINTABLE.sub(lambda m: ascii(m.group())[1:-1], message)
