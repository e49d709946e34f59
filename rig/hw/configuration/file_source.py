"""Measured configurations from a file: angles per configuration index, CSV or YAML (docs/formats.md).

The file is read and checked once, when the source is made (every error names the file, the row or
key, and what is allowed). Each `measure()` returns the angles of the configuration the runner
announced with `prepare`; a configuration the file does not list is an input error naming it, never
a guess. A file cannot see slips, so `slipped_joint` is always None.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path

from rig.errors import InputError
from rig.hw.configuration.angles import angle_problem, planar_reading_transforms
from rig.hw.seams import Clock, ConfigurationReading, MeasurementRequest
from rig.inputs.files import parse_yaml, read_text_file

FILE_FORMAT = "rig-configurations/1"
MAX_CONFIGURATIONS = 10_000


class MeasuredAnglesFile:
    """The angles [rad] of each configuration index, and their standard deviation if the file gives one."""

    def __init__(self, angles_rad: dict[int, tuple[float, ...]], sd_rad: float | None, source: str) -> None:
        self.angles_rad = angles_rad
        self.sd_rad = sd_rad
        self.source = source

    @classmethod
    def load(cls, path: Path, joint_count: int) -> MeasuredAnglesFile:
        """Read and check a CSV (`.csv`) or YAML file."""
        text = read_text_file(path, what="a measured-configurations file (CSV or YAML)")
        if path.suffix.lower() == ".csv":
            return cls._from_csv(text, str(path), joint_count)
        return cls._from_yaml(text, str(path), joint_count)

    @classmethod
    def _from_csv(cls, text: str, source: str, joint_count: int) -> MeasuredAnglesFile:
        rows = list(csv.reader(io.StringIO(text)))
        rows = [r for r in rows if r and not r[0].lstrip().startswith("#")]
        expected = ["configuration", *(f"joint_{i}_deg" for i in range(1, joint_count + 1))]
        if not rows or [c.strip() for c in rows[0][: len(expected)]] != expected:
            raise InputError(f"{source}: header: expected {','.join(expected)}[,sd_deg]")
        header = [c.strip() for c in rows[0]]
        has_sd = header[len(expected) :] == ["sd_deg"]
        if len(header) != len(expected) + has_sd:
            raise InputError(f"{source}: header: expected {','.join(expected)}[,sd_deg]")
        angles: dict[int, tuple[float, ...]] = {}
        sds: set[float] = set()
        for n, row in enumerate(rows[1:], start=2):
            where = f"{source}: row {n}"
            if len(row) != len(header):
                raise InputError(f"{where}: {len(row)} columns; allowed: {len(header)} as in the header")
            try:
                index = int(row[0])
                values = [float(c) for c in row[1 : len(expected)]]
                sd = float(row[-1]) if has_sd else None
            except ValueError:
                raise InputError(f"{where}: not a number; allowed: an index >= 1, then numbers") from None
            cls._add(angles, index, values, joint_count, where)
            if sd is not None:
                if not (math.isfinite(sd) and 0 <= sd <= 90):
                    raise InputError(f"{where}: sd_deg {sd:g}; allowed: 0-90")
                sds.add(sd)
        return cls(angles, _one_sd(sds, source), source)

    @classmethod
    def _from_yaml(cls, text: str, source: str, joint_count: int) -> MeasuredAnglesFile:
        data = parse_yaml(text, source)
        if not isinstance(data, dict) or data.get("format") != FILE_FORMAT:
            raise InputError(f"{source}: format: expected {FILE_FORMAT}")
        unknown = sorted(set(data) - {"format", "angles_deg", "sd_deg"})
        if unknown:
            raise InputError(f"{source}: {unknown[0]}: unknown key; allowed: format, angles_deg, sd_deg")
        table = data.get("angles_deg")
        if not isinstance(table, dict) or not table:
            raise InputError(f"{source}: angles_deg: expected a mapping of configuration index -> angles")
        angles: dict[int, tuple[float, ...]] = {}
        for key, values in table.items():
            where = f"{source}: angles_deg.{key}"
            if isinstance(key, bool) or not isinstance(key, int):
                raise InputError(f"{where}: the key is not an integer; allowed: a configuration index >= 1")
            if not isinstance(values, list):
                raise InputError(f"{where}: expected a list of {joint_count} angles in degrees")
            cls._add(angles, key, values, joint_count, where)
        sd = data.get("sd_deg")
        if sd is not None and (isinstance(sd, bool) or not isinstance(sd, int | float) or not 0 <= sd <= 90):
            raise InputError(f"{source}: sd_deg: {sd!r}; allowed: a number in 0-90")
        return cls(angles, None if sd is None else math.radians(float(sd)), source)

    @staticmethod
    def _add(
        angles: dict[int, tuple[float, ...]], index: int, values: Sequence[object], joints: int, where: str
    ) -> None:
        if not 1 <= index <= MAX_CONFIGURATIONS:
            raise InputError(f"{where}: configuration {index}; allowed: 1-{MAX_CONFIGURATIONS}")
        if index in angles:
            raise InputError(f"{where}: configuration {index} is listed twice; allowed: once")
        problem = angle_problem(values, joints)
        if problem is not None:
            raise InputError(f"{where}: {problem}")
        angles[index] = tuple(math.radians(float(v)) for v in values)  # type: ignore[arg-type]


def _one_sd(sds: set[float], source: str) -> float | None:
    if not sds:
        return None
    if len(sds) > 1:
        raise InputError(f"{source}: sd_deg: {len(sds)} different values; allowed: one value in every row")
    return math.radians(sds.pop())


class FileConfigurationSource:
    """`configuration.source: file`: the measured angles of the configuration being run."""

    def __init__(self, table: MeasuredAnglesFile, segment_lengths_m: Sequence[float], clock: Clock) -> None:
        self.table = table
        self._lengths = tuple(segment_lengths_m)
        self._clock = clock
        self._request: MeasurementRequest | None = None

    def prepare(self, request: MeasurementRequest) -> None:
        """Remember which configuration the next `measure()` is of."""
        self._request = request

    def measure(self) -> ConfigurationReading:
        """The file's angles of the announced configuration (an input error if it lists none)."""
        request = self._request
        index = None if request is None else request.configuration_index
        if index is None or index not in self.table.angles_rad:
            listed = ", ".join(str(i) for i in sorted(self.table.angles_rad)[:10])
            raise InputError(
                f"{self.table.source}: configuration {index}: not in the file; it lists {listed}"
                + (" ..." if len(self.table.angles_rad) > 10 else "")
            )
        angles = self.table.angles_rad[index]
        sd = self.table.sd_rad
        return ConfigurationReading(
            transforms=planar_reading_transforms(angles, self._lengths),
            time_ns=self._clock.time_ns(),
            joint_angles_rad=angles,
            uncertainty_rad=None if sd is None else (sd,) * len(angles),
        )
