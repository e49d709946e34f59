"""A logged run as replay sees it: its MCAP parts in order, and the settings recorded in them.

Each file of a run is read on its own (`rig.log.reading.reader.read_run`) and kept as a `LogPart`: a resumed
run's parts may share log times (a simulated run restarts its virtual clock at the same epoch), so
the samples of one part must never be interleaved with another's. Parts are ordered by the
`session.invocation` metadata, then by their first log time, then by name. The high-rate
`SAMPLE_TOPICS` are not held: they are read one trial's span at a time (`rig.analysis.samples`).

`RunSettings` gathers what the analysis needs from the metadata and the attachments: the test
article's geometry and g (re-parsed from the attached rig config), the detector parameters, the
fit settings, the protocol's hold after a slip (re-parsed from the attached protocol with the logged
seed) and, in simulation, the ground truth. Whatever cannot be recovered becomes a warning and a default,
never an error: a damaged log still replays.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from model.fit import DEFAULT_G, DEFAULT_LEVEL
from model.slip_detector import DetectorParams
from rig.errors import InputError, RigError
from rig.inputs.files import parse_json, parse_yaml
from rig.inputs.protocol import parse_protocol
from rig.inputs.rig_config import ArticleConfig, parse_rig_config
from rig.log.format import schemas
from rig.log.reading.reader import RunLog, mcap_files, read_run

DEFAULT_CONSTANT = "paper"
# Read by time span, a trial at a time, never whole: their memory would grow with the run.
SAMPLE_TOPICS = (schemas.LOADCELL, schemas.SERVO_STATE)


@dataclass
class LogPart:
    """One MCAP file of a run and what reading it gave."""

    path: Path
    log: RunLog
    invocation: int | None

    @property
    def name(self) -> str:
        """The file name (how tables and reports refer to the part)."""
        return self.path.name


@dataclass
class RunSettings:
    """Settings of the run recovered from its metadata and attachments (see the module docstring)."""

    run_id: str | None = None
    protocol_name: str | None = None
    article: ArticleConfig | None = None
    g: float = DEFAULT_G
    radius_m: float | None = None
    detector: DetectorParams | None = None  # the logged parameters (None: none were logged)
    detector_source: str = "defaults"
    level: float = DEFAULT_LEVEL
    constant: str = DEFAULT_CONSTANT
    seed: int | None = None
    truth: dict[str, Any] | None = None
    hold_after_slip_s: float | None = None  # the protocol's hold after a slip (the stick-slip window)


def read_parts(paths: str | os.PathLike[str] | Iterable[str | os.PathLike[str]]) -> list[LogPart]:
    """Read every MCAP file named (files or directories), each on its own, in run order.

    Raises InputError for a missing path, a directory without `.mcap` files or a non-MCAP file.
    """
    parts = []
    for path in mcap_files(paths):
        log = read_run(path, deferred=SAMPLE_TOPICS)
        invocation = _int_or_none(log.metadata.get("session", {}).get("invocation"))
        parts.append(LogPart(path=path, log=log, invocation=invocation))
    if len(parts) > 1:
        parts.sort(key=_part_order)
    return parts


def _part_order(part: LogPart) -> tuple[int, int, str]:
    first = part.log.reports[0].first_log_time_ns if part.log.reports else None
    invocation = part.invocation if part.invocation is not None else 1 << 30
    return (invocation, first if first is not None else 1 << 62, str(part.path))


def _int_or_none(text: Any) -> int | None:
    try:
        return int(str(text))
    except (TypeError, ValueError):
        return None


def _float_or_none(text: Any) -> float | None:
    try:
        return float(str(text))
    except (TypeError, ValueError):
        return None


def run_settings(parts: list[LogPart], warnings: list[str]) -> RunSettings:
    """The run's settings from the first part that has each piece; problems go to `warnings`."""
    settings = RunSettings()
    metadata: dict[str, dict[str, str]] = {}
    for part in parts:
        for name, values in part.log.metadata.items():
            metadata.setdefault(name, values)
    run_ids = {r for p in parts if (r := p.log.metadata.get("session", {}).get("run_id")) is not None}
    if len(run_ids) > 1:
        warnings.append(f"the files belong to different runs ({', '.join(sorted(run_ids))}); combined anyway")
    session = metadata.get("session", {})
    protocol_meta = metadata.get("protocol", {})
    rig_meta = metadata.get("rig", {})
    settings.run_id = session.get("run_id")
    settings.protocol_name = protocol_meta.get("name")
    settings.seed = _int_or_none(session.get("seed"))
    settings.radius_m = _float_or_none(rig_meta.get("joint_radius_m"))

    attachments = [a for part in parts for a in part.log.attachments]
    rig_name = Path(rig_meta["source"]).name if rig_meta.get("source") else None
    protocol_name = Path(protocol_meta["source"]).name if protocol_meta.get("source") else None
    rig_attachment = next((a for a in attachments if a.name == rig_name), None)
    protocol_attachment = next((a for a in attachments if a.name == protocol_name), None)

    if rig_attachment is not None:
        try:
            text = rig_attachment.data.decode("utf-8")
            config = parse_rig_config(
                parse_yaml(text, rig_attachment.name), source=rig_attachment.name, text=text
            )
            settings.article = config.article
            settings.g = config.article.g
            settings.radius_m = config.article.joint_radius_m
        except (RigError, ValueError, yaml.YAMLError) as exc:
            warnings.append(
                f"rig config attachment {rig_attachment.name}: unreadable ({exc}); geometry unknown"
            )
    elif parts and any(p.log.message_counts for p in parts):
        warnings.append(f"no rig config attachment: geometry unknown, g = {DEFAULT_G:g} m/s^2 assumed")

    detector_text = protocol_meta.get("detector")
    if detector_text:
        settings.detector = logged_detector(_detector_mapping(detector_text), "protocol metadata")
        settings.detector_source = "protocol metadata"

    if protocol_attachment is not None:
        try:
            text = protocol_attachment.data.decode("utf-8")
            joint_count = settings.article.joint_count if settings.article is not None else None
            protocol = parse_protocol(
                parse_yaml(text, protocol_attachment.name),
                source=protocol_attachment.name,
                text=text,
                seed=settings.seed or 0,
                joint_count=joint_count,
            )
            settings.hold_after_slip_s = protocol.ramp.hold_after_slip_s
            if settings.detector is None:
                settings.detector = protocol.detector
                settings.detector_source = "protocol attachment"
        except (RigError, ValueError, yaml.YAMLError) as exc:
            warnings.append(
                f"protocol attachment {protocol_attachment.name}: unreadable ({exc}); "
                "the hold after a slip (the stick-slip window) unknown"
            )

    truth_json = metadata.get("sim_truth", {}).get("json")
    if truth_json:
        try:
            settings.truth = parse_json(truth_json, "sim_truth metadata")
        except InputError:
            warnings.append("sim_truth metadata is not valid JSON; ignored")
    return settings


def _detector_mapping(text: str) -> dict[str, Any]:
    """The `protocol.detector` metadata ("k=v,k=v", Python reprs) as a mapping."""
    mapping: dict[str, Any] = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if sep:
            mapping[key.strip()] = value.strip()
    return mapping


def logged_detector(mapping: dict[str, Any], source: str) -> DetectorParams:
    """Detector parameters as a log states them; InputError naming the field if they do not parse."""
    try:
        return DetectorParams.from_mapping(mapping, source=source)
    except ValueError as exc:
        raise InputError(f"logged detector parameters: {exc}") from None


def detector_from_slips(parts: list[LogPart]) -> DetectorParams | None:
    """The detector parameters logged with the first `/rig/slip` event, if any."""
    for part in parts:
        slips = part.log.topic(schemas.SLIP)
        if slips.empty:
            continue
        row = slips.iloc[0]
        mapping = {c.removeprefix("detector."): row[c] for c in slips.columns if c.startswith("detector.")}
        return logged_detector(
            {k: (None if _is_missing(v) else v) for k, v in mapping.items()}, "slip events"
        )
    return None


def _is_missing(value: Any) -> bool:
    if value is None:
        return True
    try:
        return bool(value != value)  # NaN
    except (TypeError, ValueError):
        return False


def require_some_data(parts: list[LogPart]) -> None:
    """Refuse files that hold no rig data at all: another program's MCAP, or files too damaged to use."""
    if not parts:
        raise InputError("no MCAP files given")
    intact = all(part.log.complete for part in parts)
    rig_topics = set(schemas.TOPICS)
    names = ", ".join(str(p.path) for p in parts)
    if intact:
        if not any(rig_topics & set(part.log.topics) for part in parts):
            raise InputError(
                f"{names}: no rig topics (/rig/...) in this MCAP; allowed: a log written by `rig run`"
            )
        return
    if any(part.log.message_counts.get(topic) for part in parts for topic in rig_topics):
        return
    problems = [w for part in parts for w in part.log.warnings]
    more = f" (and {len(problems) - 1} more warnings)" if len(problems) > 1 else ""
    first = f": {problems[0]}{more}" if problems else ""
    raise InputError(f"{names}: no rig messages could be read{first}")
