"""`configuration.source: operator`: a person measures the link and types the angles at a prompt.

After bending, the prompt asks for every joint's angle in degrees (J numbers, spaces or commas);
an entry with the wrong count, a non-number or an angle beyond ±90° is refused with the reason and
asked again. After a slip it asks which joint moved (1..J, or Enter when it cannot be told). The
control loop keeps running while the prompt waits (`MeasurementRequest.keep_alive`). Without a
terminal on stdin this is an input error (a run from a script cannot have a person measure).
"""

from __future__ import annotations

import math
import re
import select
import sys
from collections.abc import Sequence
from typing import TextIO

from rig.errors import InputError
from rig.hw.configuration.angles import angle_problem, planar_reading_transforms
from rig.hw.seams import Clock, ConfigurationReading, MeasurementRequest

_SEPARATORS = re.compile(r"[,\s]+")


def parse_angles_deg(line: str, joint_count: int) -> tuple[tuple[float, ...] | None, str | None]:
    """(angles in rad, None) for a valid typed line, else (None, why it was refused)."""
    words = [w for w in _SEPARATORS.split(line.strip()) if w]
    try:
        values = [float(w) for w in words]
    except ValueError:
        return None, f"not a number in {line.strip()!r}; allowed: {joint_count} numbers in degrees"
    problem = angle_problem(values, joint_count)
    if problem is not None:
        return None, problem
    return tuple(math.radians(v) for v in values), None


def parse_joint(line: str, joint_count: int) -> tuple[int | None, str | None]:
    """(joint or None for 'cannot tell', None) for a valid answer, else (None, why it was refused)."""
    text = line.strip()
    if not text:
        return None, None
    if text.isdigit() and 1 <= int(text) <= joint_count:
        return int(text), None
    return None, f"{text!r}; allowed: a joint 1..{joint_count}, or Enter when you cannot tell"


class OperatorConfigurationSource:
    """Angles typed by a person; see the module docstring."""

    def __init__(
        self,
        segment_lengths_m: Sequence[float],
        clock: Clock,
        *,
        stdin: TextIO | None = None,
        stderr: TextIO | None = None,
    ) -> None:
        self._lengths = tuple(segment_lengths_m)
        self.joint_count = len(self._lengths)
        self._clock = clock
        self._stdin = stdin
        self._stderr = stderr
        self._request: MeasurementRequest | None = None
        self._last: ConfigurationReading | None = None

    def prepare(self, request: MeasurementRequest) -> None:
        """Remember what the next `measure()` is for."""
        self._request = request

    def measure(self) -> ConfigurationReading:
        """Ask the person (see the module docstring)."""
        request = self._request
        stdin = self._stdin if self._stdin is not None else sys.stdin
        if stdin is None or not stdin.isatty():
            raise InputError(
                "configuration.source: operator: measuring the link needs a person at a terminal; "
                "allowed without one: file, camera or command"
            )
        if request is not None and request.after_slip and self._last is not None:
            joint = self._ask_joint(stdin, request)
            return ConfigurationReading(
                transforms=self._last.transforms, time_ns=self._clock.time_ns(), slipped_joint=joint
            )
        angles = self._ask_angles(stdin, request)
        reading = ConfigurationReading(
            transforms=planar_reading_transforms(angles, self._lengths),
            time_ns=self._clock.time_ns(),
            joint_angles_rad=angles,
        )
        self._last = reading
        return reading

    def _ask_angles(self, stdin: TextIO, request: MeasurementRequest | None) -> tuple[float, ...]:
        where = (
            ""
            if request is None or request.configuration_index is None
            else f" of configuration {request.configuration_index}"
        )
        commanded = ""
        if request is not None and request.commanded_angles_rad is not None:
            commanded = (
                " (commanded: "
                + " ".join(f"{math.degrees(a):.1f}" for a in request.commanded_angles_rad)
                + ")"
            )
        prompt = f"Measured joint angles{where} in degrees, joint 1 first{commanded}: "
        while True:
            line = self._read_line(stdin, prompt, request)
            angles, problem = parse_angles_deg(line, self.joint_count)
            if angles is not None:
                return angles
            self._say(f"refused: {problem}")

    def _ask_joint(self, stdin: TextIO, request: MeasurementRequest) -> int | None:
        prompt = f"Which joint moved in the slip (1..{self.joint_count}, Enter: cannot tell)? "
        while True:
            joint, problem = parse_joint(self._read_line(stdin, prompt, request), self.joint_count)
            if problem is None:
                return joint
            self._say(f"refused: {problem}")

    def _read_line(self, stdin: TextIO, prompt: str, request: MeasurementRequest | None) -> str:
        self._say(f"\n>>> {prompt}", end="")
        if request is not None:
            while not select.select([stdin], [], [], 0)[0]:
                request.keep_alive()
        line = stdin.readline()
        if not line:
            raise InputError("configuration.source: operator: the terminal closed while measuring")
        return line

    def _say(self, text: str, end: str = "\n") -> None:
        print(text, end=end, file=self._stderr if self._stderr is not None else sys.stderr, flush=True)
