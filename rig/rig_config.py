"""The rig config: which devices, on which ports, with which roles, limits and test article.

A rig config is YAML, validated on load: every error names the file, the field path and what is
allowed. `kind: simulated` builds the byte-level simulated rig (the built-in default is package
data, `rig/data/simulated.yaml`, so that an installed `rig` has it); `kind: hardware` opens real
serial ports (template: `protocols/rigs/hardware.example.yaml`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from typing import Any

from model.gravity import PAPER_G_M_S2
from rig.errors import ConfigError
from rig.files import parse_yaml, read_text_file
from rig.validate import Section
from rig.vocabulary import SERVO_BAUDS, LoadCellFormatName, RigKind, ServoModel, ServoRole, SlipKind

SIM_PRESETS = ("link1", "link2")
# The built-in simulated rig, shipped as package data. A package installed as a directory (a wheel or
# an editable install) gives a real path, which the journal records for `--resume`.
DEFAULT_RIG_CONFIG = Path(str(files("rig") / "data" / "simulated.yaml"))
MAX_JOINTS = 100
MAX_PORT_CHARS = 4096


@dataclass(frozen=True)
class ServoSpec:
    """One servo on the bus and what it does on the rig."""

    servo_id: int
    role: ServoRole
    model: ServoModel


@dataclass(frozen=True)
class ServoBusConfig:
    """The Dynamixel bus: port, baud rate, servos, retries."""

    port: str
    baud: int
    servos: tuple[ServoSpec, ...]
    retries: int
    watchdog_ms: int

    @property
    def winch(self) -> ServoSpec:
        """The servo with role `winch` (validation guarantees exactly one)."""
        return next(s for s in self.servos if s.role == ServoRole.WINCH)

    @property
    def benders(self) -> tuple[ServoSpec, ...]:
        """The servos with role `bender`, in config order."""
        return tuple(s for s in self.servos if s.role == ServoRole.BENDER)


@dataclass(frozen=True)
class LoadCellConfig:
    """The inline load cell: port, baud rate, line format, calibration file."""

    port: str
    baud: int
    format: LoadCellFormatName
    calibration_path: Path | None


@dataclass(frozen=True)
class RigLimits:
    """Hard limits checked before anything moves and enforced by interlocks during a run."""

    force_ceiling_n: float
    winch_current_limit_a: float
    stale_timeout_s: float
    max_winch_travel_rev: float


@dataclass(frozen=True)
class ArticleConfig:
    """The test article: geometry in the link-file format (straight configuration) and joint radius."""

    joint_radius_m: float
    segment_lengths_m: tuple[float, ...]
    point_m: tuple[float, float, float]
    direction: tuple[float, float, float]
    g: float

    @property
    def joint_count(self) -> int:
        """Number of joints J (components are J + 1, the base included)."""
        return len(self.segment_lengths_m)


# The servos' Bus Watchdog unless a config says otherwise (0 turns it off): a servo that hears nothing
# from the host this long stops where it is. The runner talks to every servo each control period.
DEFAULT_WATCHDOG_MS = 500

# Which faults each simulated device can be given (`simulation.faults:`, docs in protocols/README.md).
SERVO_FAULT_KINDS = ("drop", "corrupt", "delay", "silent", "disconnect", "overload")
FAULT_KINDS: dict[str, tuple[str, ...]] = {
    "servos": SERVO_FAULT_KINDS,
    "winch": SERVO_FAULT_KINDS,
    "bender": SERVO_FAULT_KINDS,
    "loadcell": ("garble", "checksum", "gap", "silent", "disconnect"),
    "logger": ("write_error",),
}
# Kinds that happen per reply or per line with a probability (`rate`); the others happen at a time.
RATE_FAULT_KINDS = frozenset({"drop", "corrupt", "delay", "garble", "checksum"})


@dataclass(frozen=True)
class FaultConfig:
    """One fault to inject into the simulated rig: a rate (per reply or line) or an event at `at_s`.

    `at_s` counts from the start of the invocation's virtual clock; `duration_s` None means to the
    end of the run. A `logger` `write_error` fails the log's writes once it holds `after_bytes`.
    """

    device: str
    kind: str
    rate: float | None = None
    at_s: float | None = None
    duration_s: float | None = None
    delay_ms: float | None = None
    after_bytes: int | None = None


# Allowed ranges of the slip-kind parameters: (lowest, highest), both inclusive.
SLIP_RANGES: dict[str, tuple[float, float]] = {
    "small_drop_fraction": (0.005, 0.5),
    "creep_duration_s": (0.01, 10.0),
    "creep_drop_fraction": (0.001, 0.5),
    "stick_slip_drops": (2, 20),
    "stick_slip_drop_fraction": (0.005, 0.5),
    "stick_slip_dwell_s": (0.002, 1.0),
    "other_joint_load_fraction": (0.05, 0.99),
    "other_joint_drop_fraction": (0.005, 0.9),
}


@dataclass(frozen=True)
class SlipKindMix:
    """Which kinds of slip the simulated joints make, with what probability, and their parameters.

    `probabilities` follows `SlipKind`'s order and sums to 1; each trial draws one kind. The ranges
    (lowest, highest) are drawn uniformly per trial (`stick_slip_drops` as an integer):

    * sudden: the joint turns until its moment is `kinetic_ratio` x static (the preset's 0.8).
    * small_drop: the same with a drop of `small_drop_fraction` of the peak (3-15 % by default).
    * creep: at the static load the joint yields slowly: over `creep_duration_s` it turns just
      enough to keep the tension on a line falling from the peak by `creep_drop_fraction`.
    * stick_slip: `stick_slip_drops` drops, each `stick_slip_drop_fraction` of the tension at its
      onset, separated by a dwell of `stick_slip_dwell_s` (or less, if the winch re-tensions the
      line to the first peak sooner).
    * other_joint (joint estimation only; a link-validation trial makes it sudden): a neighbouring
      joint of the fixture slips first, at `other_joint_load_fraction` of the specimen's slip load,
      dropping the tension by `other_joint_drop_fraction`; the configuration source names that
      joint with `other_joint_report_probability`.
    * no_slip: the trial's capacities are `no_slip_capacity_factor` x their draw, so the ramp
      reaches its force limit first.
    """

    probabilities: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    small_drop_fraction: tuple[float, float] = (0.03, 0.15)
    creep_duration_s: tuple[float, float] = (0.05, 2.0)
    creep_drop_fraction: tuple[float, float] = (0.02, 0.10)
    stick_slip_drops: tuple[float, float] = (2, 5)
    stick_slip_drop_fraction: tuple[float, float] = (0.03, 0.10)
    stick_slip_dwell_s: tuple[float, float] = (0.01, 0.04)
    other_joint_load_fraction: tuple[float, float] = (0.5, 0.9)
    other_joint_drop_fraction: tuple[float, float] = (0.05, 0.20)
    other_joint_report_probability: float = 1.0
    no_slip_capacity_factor: float = 100.0  # slip loads beyond any force ceiling a rig config allows (500 N)

    def __post_init__(self) -> None:
        """Check ranges; a `ValueError` names the field and what is allowed."""
        p = self.probabilities
        if len(p) != len(SlipKind) or min(p) < 0 or abs(sum(p) - 1.0) > 1e-9:
            raise ValueError(f"slip kind probabilities {p}; allowed: {len(SlipKind)} numbers >= 0, sum 1")
        for name, (lo, hi) in SLIP_RANGES.items():
            first, last = getattr(self, name)
            if not lo <= first <= last <= hi:
                raise ValueError(
                    f"{name} = [{first}, {last}]; allowed: {lo:g} <= lowest <= highest <= {hi:g}"
                )
        if not 0 <= self.other_joint_report_probability <= 1:
            raise ValueError("other_joint_report_probability; allowed: 0-1")
        if not 1 < self.no_slip_capacity_factor <= 1000:
            raise ValueError("no_slip_capacity_factor; allowed: > 1 and <= 1000")

    def probability(self, kind: SlipKind) -> float:
        """The probability of one kind."""
        return self.probabilities[list(SlipKind).index(kind)]


# Shapes of the trial-to-trial scatter of a joint's capacity, stated for the slip mass m it gives:
# sd(m)^2 = a^2 + (b m)^2 with a = 0 (multiplicative), b = 0 (additive) or both (mixed).
SCATTER_SHAPES = ("multiplicative", "additive", "mixed")
MAX_SCATTER_A_KG = 10.0
MAX_SCATTER_B = 0.5


@dataclass(frozen=True)
class CapacityScatter:
    """The scatter shape (`simulation.scatter:`); `b` None keeps the preset's relative sd."""

    shape: str = "multiplicative"
    a_kg: float = 0.0  # additive sd of the slip mass [kg]
    b: float | None = None  # relative sd of the slip mass

    def __post_init__(self) -> None:
        """Check the shape and that it has the parameters it needs; `ValueError` otherwise."""
        if self.shape not in SCATTER_SHAPES:
            raise ValueError(f"scatter shape {self.shape!r}; allowed: {', '.join(SCATTER_SHAPES)}")
        if not 0 <= self.a_kg <= MAX_SCATTER_A_KG:
            raise ValueError(f"scatter a_kg = {self.a_kg}; allowed: 0-{MAX_SCATTER_A_KG:g}")
        if self.b is not None and not 0 <= self.b <= MAX_SCATTER_B:
            raise ValueError(f"scatter b = {self.b}; allowed: 0-{MAX_SCATTER_B:g}")
        if self.shape == "multiplicative" and self.a_kg != 0:
            raise ValueError("scatter a_kg is for shape additive or mixed; multiplicative has a = 0")
        if self.shape == "additive" and self.b is not None:
            raise ValueError("scatter b is for shape multiplicative or mixed; additive has b = 0")
        if self.shape != "multiplicative" and self.a_kg == 0:
            raise ValueError(f"scatter shape {self.shape} needs a_kg > 0")


# Allowed ranges of the load-cell artefacts (`simulation.loadcell:`): (lowest, highest).
ARTEFACT_RANGES: dict[str, tuple[float, float]] = {
    "noise_scale": (0.0, 100.0),
    "drift_n_per_s": (-10.0, 10.0),
    "wander_n_per_sqrt_s": (0.0, 10.0),
    "spike_rate_per_s": (0.0, 100.0),
    "spike_n": (0.0, 100.0),
    "hum_n": (0.0, 10.0),
    "hum_hz": (1.0, 500.0),
    "gain_creep_fraction": (-0.2, 0.2),
    "gain_creep_time_constant_s": (0.1, 1e5),
}


@dataclass(frozen=True)
class LoadCellArtefacts:
    """What a real load cell adds to the tension besides white noise; all off by default.

    The cell reports, before its ADC noise and quantisation,
        tension * (1 + gain_creep_fraction * (1 - exp(-t / gain_creep_time_constant_s)))
        + drift_n_per_s * t + W(t) + hum_n * sin(2 pi hum_hz t + phase) + spikes
    with t the time since power-on, W a random walk of wander_n_per_sqrt_s per sqrt(second) (the
    zero wandering), and single-sample spikes at `spike_rate_per_s` on average, each of either
    sign and of a size uniform in [spike_n / 2, spike_n]. `noise_scale` multiplies the cell's
    white noise. The phase and every random draw come from the seed's own artefact stream.
    """

    noise_scale: float = 1.0
    drift_n_per_s: float = 0.0
    wander_n_per_sqrt_s: float = 0.0
    spike_rate_per_s: float = 0.0
    spike_n: float = 0.0
    hum_n: float = 0.0
    hum_hz: float = 50.0
    gain_creep_fraction: float = 0.0
    gain_creep_time_constant_s: float = 60.0

    def __post_init__(self) -> None:
        """Check ranges; a `ValueError` names the field and what is allowed."""
        for name, (lo, hi) in ARTEFACT_RANGES.items():
            value = getattr(self, name)
            if not (math.isfinite(value) and lo <= value <= hi):
                raise ValueError(f"{name} = {value}; allowed: {lo:g}-{hi:g}")

    @property
    def active(self) -> bool:
        """Whether any artefact (besides the noise level) is on."""
        return bool(
            self.drift_n_per_s
            or self.wander_n_per_sqrt_s
            or (self.spike_rate_per_s and self.spike_n)
            or self.hum_n
            or self.gain_creep_fraction
        )


@dataclass(frozen=True)
class SimulationConfig:
    """Simulated-world settings (only for `kind: simulated`)."""

    preset: str
    loadcell_rate_hz: float
    noise_scale: float
    torsion_weak_joint: int | None
    faults: tuple[FaultConfig, ...] = ()
    slips: SlipKindMix = SlipKindMix()
    scatter: CapacityScatter = CapacityScatter()
    loadcell: LoadCellArtefacts = LoadCellArtefacts()


@dataclass(frozen=True)
class RigConfig:
    """A validated rig config."""

    source: Path
    text: str
    name: str
    kind: RigKind
    spool_radius_m: float
    line_stiffness_n_per_m: float
    servos: ServoBusConfig
    loadcell: LoadCellConfig
    article: ArticleConfig
    limits: RigLimits
    simulation: SimulationConfig | None = field(default=None)

    def as_metadata(self) -> dict[str, str]:
        """A flat str->str summary for the MCAP `rig` metadata record."""
        return {
            "name": self.name,
            "kind": self.kind.value,
            "source": str(self.source),
            "servo_port": self.servos.port,
            "servo_baud": str(self.servos.baud),
            "servos": ",".join(f"{s.servo_id}:{s.role}:{s.model}" for s in self.servos.servos),
            "loadcell_port": self.loadcell.port,
            "loadcell_format": self.loadcell.format,
            "spool_radius_m": repr(self.spool_radius_m),
            "joint_radius_m": repr(self.article.joint_radius_m),
            "joints": str(self.article.joint_count),
            "force_ceiling_n": repr(self.limits.force_ceiling_n),
        }


def load_rig_config(path: str | Path | None = None) -> RigConfig:
    """Load and validate a rig config; the built-in simulated rig when `path` is None."""
    p = Path(path) if path is not None else DEFAULT_RIG_CONFIG
    text = read_text_file(p, what="a rig config YAML file")
    return parse_rig_config(parse_yaml(text, str(p)), source=str(p), text=text, base_dir=p.parent)


# `extends: simulated` starts a config from the built-in simulated rig; the file's own fields are
# merged over it (mappings key by key, anything else replaced), so a scenario states only what differs.
BASE_CONFIGS = {"simulated": DEFAULT_RIG_CONFIG}


def _extended(top: Section) -> dict[str, Any]:
    name = top.string("extends", choices=list(BASE_CONFIGS))
    base_path = BASE_CONFIGS[name]
    base = parse_yaml(read_text_file(base_path, what="a rig config YAML file"), str(base_path))
    own = {k: v for k, v in top.data.items() if k != "extends"}
    merged: dict[str, Any] = _merged(base, own)
    return merged


def _merged(base: Any, override: Any) -> Any:
    if isinstance(base, dict) and isinstance(override, dict):
        return {**base, **{k: _merged(base.get(k), v) for k, v in override.items()}}
    return override


def parse_rig_config(data: Any, *, source: str, text: str = "", base_dir: Path | None = None) -> RigConfig:
    """Validate a parsed rig config mapping (one that `extends:` a built-in config is merged first)."""
    if isinstance(data, dict) and "extends" in data:
        data = _extended(Section(data, source))
    top = Section(data, source)
    top.reject_unknown(
        [
            "name",
            "kind",
            "spool_radius_m",
            "line_stiffness_n_per_m",
            "servos",
            "loadcell",
            "article",
            "limits",
            "simulation",
        ]
    )
    kind = RigKind(top.string("kind", choices=tuple(RigKind)))
    servos = _servo_bus(top.section("servos"))
    loadcell = _loadcell(top.section("loadcell"), base_dir or Path("."))
    article = _article(top.section("article"))
    limits = _limits(top.section("limits"))
    simulation = None
    if kind == RigKind.SIMULATED:
        simulation = _simulation(top.section("simulation", default={}), article)
    elif top.has("simulation"):
        raise top.error("simulation", "only allowed with kind: simulated")
    return RigConfig(
        source=Path(source),
        text=text,
        name=top.string("name", default=Path(source).stem),
        kind=kind,
        spool_radius_m=top.number("spool_radius_m", min_value=0.001, max_value=0.2),
        line_stiffness_n_per_m=top.number(
            "line_stiffness_n_per_m", default=2000.0, min_value=1.0, max_value=1e7
        ),
        servos=servos,
        loadcell=loadcell,
        article=article,
        limits=limits,
        simulation=simulation,
    )


def _servo_bus(sec: Section) -> ServoBusConfig:
    sec.reject_unknown(["port", "baud", "ids", "retries", "watchdog_ms"])
    baud = sec.integer("baud", default=1_000_000)
    if baud not in SERVO_BAUDS:
        raise sec.error("baud", f"{baud} is not a Dynamixel baud rate; allowed: {SERVO_BAUDS}")
    specs: list[ServoSpec] = []
    for i, item in enumerate(sec.sequence("ids", min_length=1, max_length=253)):
        entry = Section(item, sec.source, f"{sec.field('ids')}[{i}]")
        entry.reject_unknown(["id", "role", "model"])
        specs.append(
            ServoSpec(
                servo_id=entry.integer("id", min_value=0, max_value=252),
                role=ServoRole(entry.string("role", choices=tuple(ServoRole))),
                model=ServoModel(
                    entry.string("model", default=ServoModel.XM430_W350, choices=tuple(ServoModel))
                ),
            )
        )
    ids = [s.servo_id for s in specs]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise sec.error("ids", f"duplicate servo id(s) {duplicates}; each id must appear once")
    winches = [s for s in specs if s.role == ServoRole.WINCH]
    if len(winches) != 1:
        raise sec.error("ids", f"expected exactly one servo with role 'winch', found {len(winches)}")
    if winches[0].model == ServoModel.XL430_W250:
        raise sec.error(
            "ids", "the winch needs current-based position mode (5); XL430-W250 has no current control"
        )
    return ServoBusConfig(
        port=_port(sec),
        baud=baud,
        servos=tuple(specs),
        retries=sec.integer("retries", default=2, min_value=0, max_value=10),
        watchdog_ms=sec.integer("watchdog_ms", default=DEFAULT_WATCHDOG_MS, min_value=0, max_value=127 * 20),
    )


def _port(sec: Section) -> str:
    port = sec.string("port")
    if not 0 < len(port) <= MAX_PORT_CHARS:
        raise sec.error("port", f"{len(port)} characters; allowed: a serial port name of 1-{MAX_PORT_CHARS}")
    return port


def _loadcell(sec: Section, base_dir: Path) -> LoadCellConfig:
    sec.reject_unknown(["port", "baud", "format", "calibration"])
    calibration = sec.string("calibration", default="")
    return LoadCellConfig(
        port=_port(sec),
        baud=sec.integer("baud", default=921_600, min_value=1200, max_value=4_000_000),
        format=LoadCellFormatName(
            sec.string("format", default=LoadCellFormatName.RIG_LC1, choices=tuple(LoadCellFormatName))
        ),
        calibration_path=(base_dir / calibration) if calibration else None,
    )


def _article(sec: Section) -> ArticleConfig:
    sec.reject_unknown(["joint_radius_m", "segment_lengths_m", "load", "g"])
    load = sec.section("load")
    load.reject_unknown(["point_m", "direction"])
    direction = load.numbers("direction", length=3, min_value=-1000.0, max_value=1000.0)
    if math.hypot(*direction) < 1e-6:
        raise load.error(
            "direction", "the load direction is zero; allowed: a 3-vector of length >= 1e-6, each |x| <= 1000"
        )
    return ArticleConfig(
        joint_radius_m=sec.number("joint_radius_m", min_value=0.0001, max_value=0.1),
        segment_lengths_m=tuple(
            sec.numbers("segment_lengths_m", max_length=MAX_JOINTS, min_value=0.001, max_value=1.0)
        ),
        point_m=tuple(load.numbers("point_m", length=3, min_value=-10.0, max_value=10.0)),  # type: ignore[arg-type]
        direction=tuple(direction),  # type: ignore[arg-type]
        g=sec.number("g", default=PAPER_G_M_S2, min_value=0.1, max_value=100.0),
    )


def _limits(sec: Section) -> RigLimits:
    sec.reject_unknown(
        ["force_ceiling_n", "winch_current_limit_a", "stale_timeout_s", "max_winch_travel_rev"]
    )
    return RigLimits(
        force_ceiling_n=sec.number("force_ceiling_n", min_value=0.1, max_value=500.0),
        winch_current_limit_a=sec.number("winch_current_limit_a", min_value=0.01, max_value=3.2),
        stale_timeout_s=sec.number("stale_timeout_s", default=0.2, min_value=0.005, max_value=10.0),
        max_winch_travel_rev=sec.number("max_winch_travel_rev", default=20.0, min_value=0.1, max_value=255.0),
    )


def _simulation(sec: Section, article: ArticleConfig) -> SimulationConfig:
    sec.reject_unknown(
        [
            "preset",
            "loadcell_rate_hz",
            "noise_scale",
            "torsion_weak_joint",
            "faults",
            "slips",
            "scatter",
            "loadcell",
        ]
    )
    weak = sec.raw("torsion_weak_joint", default=None)
    if weak is not None:
        weak = sec.integer("torsion_weak_joint", min_value=1, max_value=article.joint_count)
    faults = tuple(
        _fault(Section(item, sec.source, sec.field("faults") + f"[{i}]"))
        for i, item in enumerate(sec.sequence("faults", default=[]))
    )
    return SimulationConfig(
        preset=sec.string("preset", default="link1", choices=SIM_PRESETS),
        loadcell_rate_hz=sec.number("loadcell_rate_hz", default=1000.0, min_value=10.0, max_value=2000.0),
        noise_scale=sec.number("noise_scale", default=1.0, min_value=0.0, max_value=10.0),
        torsion_weak_joint=weak,
        faults=faults,
        slips=_slips(sec.section("slips", default={})),
        scatter=_scatter(sec.section("scatter", default={})),
        loadcell=_artefacts(sec.section("loadcell", default={})),
    )


def _slips(sec: Section) -> SlipKindMix:
    """`simulation.slips`: the mix of slip kinds (probabilities summing to 1) and their ranges."""
    defaults = SlipKindMix()
    sec.reject_unknown(["mix", *SLIP_RANGES, "other_joint_report_probability", "no_slip_capacity_factor"])
    probabilities = defaults.probabilities
    if sec.has("mix"):
        mix = sec.section("mix")
        mix.reject_unknown(tuple(SlipKind))
        probabilities = tuple(
            mix.number(kind, default=0.0, min_value=0.0, max_value=1.0) for kind in SlipKind
        )
        if abs(sum(probabilities) - 1.0) > 1e-6:
            raise sec.error("mix", f"the probabilities sum to {sum(probabilities):g}; allowed: they sum to 1")
        probabilities = tuple(p / sum(probabilities) for p in probabilities)
    ranges: dict[str, tuple[float, float]] = {}
    for name, (lo, hi) in SLIP_RANGES.items():
        pair = sec.numbers(name, length=2, min_value=lo, max_value=hi, default=list(getattr(defaults, name)))
        if pair[0] > pair[1]:
            raise sec.error(
                name, f"[{pair[0]:g}, {pair[1]:g}]; allowed: [lowest, highest] within {lo:g}-{hi:g}"
            )
        if name == "stick_slip_drops" and any(x != int(x) for x in pair):
            raise sec.error(name, f"[{pair[0]:g}, {pair[1]:g}]; allowed: whole numbers within {lo:g}-{hi:g}")
        ranges[name] = (pair[0], pair[1])
    return SlipKindMix(
        probabilities=probabilities,
        other_joint_report_probability=sec.number(
            "other_joint_report_probability",
            default=defaults.other_joint_report_probability,
            min_value=0.0,
            max_value=1.0,
        ),
        no_slip_capacity_factor=sec.number(
            "no_slip_capacity_factor",
            default=defaults.no_slip_capacity_factor,
            min_value=1.0,
            max_value=1000.0,
            min_exclusive=True,
        ),
        **ranges,
    )


def _scatter(sec: Section) -> CapacityScatter:
    """`simulation.scatter`: shape multiplicative (b), additive (a_kg) or mixed (both)."""
    sec.reject_unknown(["shape", "a_kg", "b"])
    shape = sec.string("shape", default="multiplicative", choices=SCATTER_SHAPES)
    if shape == "multiplicative" and sec.has("a_kg"):
        raise sec.error("a_kg", "only for shape additive or mixed; allowed: remove it, or change the shape")
    if shape == "additive" and sec.has("b"):
        raise sec.error(
            "b", "only for shape multiplicative or mixed; allowed: remove it, or change the shape"
        )
    a_kg = 0.0
    if shape != "multiplicative":
        a_kg = sec.number("a_kg", min_value=0.0, max_value=MAX_SCATTER_A_KG, min_exclusive=True)
    b = None
    if sec.has("b"):
        b = sec.number("b", min_value=0.0, max_value=MAX_SCATTER_B)
    return CapacityScatter(shape=shape, a_kg=a_kg, b=b)


def _artefacts(sec: Section) -> LoadCellArtefacts:
    """`simulation.loadcell`: the simulated cell's artefacts (all off by default)."""
    sec.reject_unknown(list(ARTEFACT_RANGES))
    defaults = LoadCellArtefacts()
    values = {
        name: sec.number(name, default=getattr(defaults, name), min_value=lo, max_value=hi)
        for name, (lo, hi) in ARTEFACT_RANGES.items()
    }
    return LoadCellArtefacts(**values)


def _fault(sec: Section) -> FaultConfig:
    """One entry of `simulation.faults`: which fields it needs depends on its kind."""
    sec.reject_unknown(["device", "kind", "rate", "at_s", "duration_s", "delay_ms", "after_bytes"])
    device = sec.string("device", choices=list(FAULT_KINDS))
    kind = sec.string("kind", choices=FAULT_KINDS[device])
    if device == "logger":
        after = sec.integer("after_bytes", min_value=1, max_value=2**40)
        return FaultConfig(device, kind, after_bytes=after)
    if kind in RATE_FAULT_KINDS:
        rate = sec.number("rate", min_value=0.0, max_value=1.0)
        delay = None
        if kind == "delay":
            delay = sec.number("delay_ms", default=50.0, min_value=0.0, max_value=10_000.0)
        return FaultConfig(device, kind, rate=rate, delay_ms=delay)
    at_s = sec.number("at_s", min_value=0.0, max_value=1e6)
    duration = sec.raw("duration_s", default=None)
    if duration is not None:
        duration = sec.number("duration_s", min_value=0.0, max_value=1e6, min_exclusive=True)
    return FaultConfig(device, kind, at_s=at_s, duration_s=duration)


def require_simulated(config: RigConfig) -> SimulationConfig:
    """The simulation settings of a simulated rig (a ConfigError for a hardware rig)."""
    if config.simulation is None:
        raise ConfigError(f"{config.source}: kind: this command needs kind: simulated, got {config.kind}")
    return config.simulation
