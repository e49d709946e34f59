"""The rig config: which devices, on which ports, with which roles, limits and test article.

A rig config is YAML, validated on load: every error names the file, the field path and what is
allowed. `kind: simulated` builds the byte-level simulated rig (the built-in default is package
data, `rig/data/simulated.yaml`, so that an installed `rig` has it); `kind: hardware` opens real
serial ports (template: `protocols/rigs/hardware.example.yaml`).

The `simulation:` section is the simulator's (`rig.sim.settings` parses and checks it, and every
command that loads a config for a rig has it checked); this module keeps it as written, and reads of
it only the simulated cell's rate, which a simulated rig's `loadcell.rate_hz` defaults to.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from importlib.resources import files
from pathlib import Path
from typing import Any

from model.field_spec import choice, custom, inline_text, integer, number, numbers, section
from model.field_spec import text as text_field
from model.gravity import PAPER_G_M_S2
from rig.errors import ConfigError
from rig.inputs.files import parse_yaml, read_text_file
from rig.inputs.servo_ratings import (
    MOTOR_RATINGS,
    STALL_TENSION_CEILING_RATIO,
    current_for_tension_a,
    stall_tension_n,
    winch_models,
)
from rig.inputs.validate import Section, read_field, read_fields, reject_undeclared
from rig.vocabulary import (
    LOADCELL_FORMAT_TRAITS,
    SERVO_BAUDS,
    UART_BITS_PER_BYTE,
    ConfigurationSourceKind,
    LoadCellFormatName,
    RigKind,
    ServoModel,
    ServoRole,
)

# The built-in simulated rig, shipped as package data. A package installed as a directory (a wheel or
# an editable install) gives a real path, which the journal records for `--resume`.
DEFAULT_RIG_CONFIG = Path(str(files("rig") / "data" / "simulated.yaml"))
MAX_JOINTS = 100
MAX_PORT_CHARS = 4096


@dataclass(frozen=True)
class ServoSpec:
    """One servo on the bus and what it does on the rig."""

    servo_id: int = field(metadata=integer(0, 252, key="id"))
    role: ServoRole = field(metadata=choice(ServoRole))
    model: ServoModel = field(default=ServoModel.XM430_W350, metadata=choice(ServoModel))
    component: int | None = field(
        default=None,
        metadata=custom(
            default_doc="none",
            allowed_doc="1..J, each component at most once; benders only",
            doc="the link component whose fork this bender drives (docs/bending.md)",
        ),
    )


# The servos' Bus Watchdog unless a config says otherwise (0 turns it off): a servo that hears nothing
# from the host this long stops where it is. The runner talks to every servo each control period.
DEFAULT_WATCHDOG_MS = 500
# How long the release keeps trying a servo bus that went quiet before it gives up (rig config may say).
DEFAULT_RELEASE_PATIENCE_S = 10.0
# Once the winch is back from a release, how long the load cell has to read the line slack (a line
# relaxing, a slow cell's next sample) before the safe state is reported not verified (rig config may say).
DEFAULT_SLACK_SETTLE_S = 1.0
# How long the release of the line waits for the winch beyond its travel time (rig config may say):
# interlocks are off by then, and the load cell may be what failed, so arrival at the zero-tension
# angle is all it waits for.
DEFAULT_RELEASE_MARGIN_S = 2.0
# After a device fault and the release of the line, how long the rig has to answer healthily again
# (rig config may say).
DEFAULT_RECOVERY_GRACE_S = 2.0
_PORT = f"serial port, 1-{MAX_PORT_CHARS} characters"


@dataclass(frozen=True, kw_only=True)
class ServoBusConfig:
    """The Dynamixel bus: port, baud rate, servos, retries."""

    port: str = field(
        metadata=text_field(allowed_doc=f"{_PORT} (ignored by the simulated rig; `sim://dxl` by convention)")
    )
    baud: int = field(default=1_000_000, metadata=custom(allowed_doc=", ".join(str(b) for b in SERVO_BAUDS)))
    servos: tuple[ServoSpec, ...] = field(
        metadata=custom(
            key="ids",
            allowed_doc=f"list of 1-253 `{inline_text(ServoSpec)}`; ids unique; exactly one winch, a model "
            "with current-based position control (mode 5; not the XL430, XC430, their 2X versions or the "
            "MX-28(2.0))",
        )
    )
    retries: int = field(default=2, metadata=integer(0, 10, doc="retries per bus transaction"))
    watchdog_ms: int = field(
        default=DEFAULT_WATCHDOG_MS,
        metadata=integer(0, 127 * 20, unit="ms", doc="Bus Watchdog, 20 ms units; 0 turns it off"),
    )
    release_patience_s: float = field(
        default=DEFAULT_RELEASE_PATIENCE_S,
        metadata=number(
            0.0,
            600.0,
            unit="s",
            doc="how long the release of the line keeps trying a servo bus that stopped answering (a USB "
            "adapter that hangs); once it answers, the safe state is verified and the trial repeated; a bus "
            "silent for longer ends the run (exit 1)",
        ),
    )
    release_margin_s: float = field(
        default=DEFAULT_RELEASE_MARGIN_S,
        metadata=number(
            0.1,
            60.0,
            unit="s",
            doc="how long the release of the line waits for the winch beyond twice its travel time at the "
            "speed in force; a winch not back at its zero-tension angle by then leaves the safe state not "
            "verified",
        ),
    )

    @property
    def winch(self) -> ServoSpec:
        """The servo with role `winch` (validation guarantees exactly one)."""
        return next(s for s in self.servos if s.role == ServoRole.WINCH)

    @property
    def benders(self) -> tuple[ServoSpec, ...]:
        """The servos with role `bender`, in config order."""
        return tuple(s for s in self.servos if s.role == ServoRole.BENDER)


@dataclass(frozen=True, kw_only=True)
class LoadCellConfig:
    """The inline load cell: port, baud rate, line format, calibration file."""

    port: str = field(
        metadata=text_field(
            allowed_doc=f"serial port or pyserial URL, 1-{MAX_PORT_CHARS} characters (`sim://loadcell` by "
            "convention when simulated)"
        )
    )
    baud: int = field(
        default=115_200,
        metadata=integer(
            1200,
            4_000_000,
            doc="must carry `rate_hz` lines of the format (8N1, the longest line): rig-lc1 at 115200 "
            "carries up to 311/s, at 921600 up to 2490/s",
        ),
    )
    format: LoadCellFormatName = field(
        default=LoadCellFormatName.RIG_LC1, metadata=choice(LoadCellFormatName)
    )
    calibration_path: Path | None = field(
        default=None,
        metadata=custom(
            key="calibration",
            allowed_doc="a §6 file, relative to the config; required on hardware (`rig run --dry-run` only "
            "notes one not made yet); when given it must be valid for a simulated rig too (`rig run`, also "
            "`--dry-run`, reads it), though the simulated cell keeps its nominal calibration",
        ),
    )
    capacity_n: float | None = field(
        default=None,
        metadata=number(
            0.1,
            100_000.0,
            unit="N",
            optional=True,
            doc="the cell's rated capacity; `rig check` checks that the force ceiling and the winch's "
            "stall tension stay below it",
        ),
    )
    # Appended fields (issue 21): the cell's rate and the boot grace after opening its port.
    rate_hz: float | None = field(
        default=None,
        metadata=number(
            0.1,
            2000.0,
            unit="1/s",
            default_doc="none (simulated: `simulation.loadcell_rate_hz`)",
            doc="samples per second the cell sends, or a polled format's poll rate (required for "
            "one); sets the stale timeout's default and the detector's and the ramp's rate-derived "
            "defaults, and is checked against `baud`; a run warns when the measured rate is more "
            "than 20 % off",
        ),
    )
    boot_grace_s: float = field(
        default=3.0,
        metadata=number(
            0.0,
            30.0,
            unit="s",
            doc="after opening the port, how long the first valid sample may take (an Arduino "
            "resets when its port opens and is silent 1-3 s); then `limits.stale_timeout_s` applies",
        ),
    )
    slack_settle_s: float = field(
        default=DEFAULT_SLACK_SETTLE_S,
        metadata=number(
            0.1,
            60.0,
            unit="s",
            doc="once the release of the line has the winch back at its zero-tension angle, how long the "
            "cell has to read the line slack (a line relaxing, a slow cell's next sample) before the safe "
            "state is reported not verified",
        ),
    )


@dataclass(frozen=True, kw_only=True)
class RigLimits:
    """Hard limits checked before anything moves and enforced by interlocks during a run."""

    force_ceiling_n: float = field(metadata=number(0.1, 500.0, unit="N", doc="tension interlock"))
    winch_current_limit_a: float = field(
        metadata=number(
            0.01,
            3.2,
            unit="A",
            doc="written to the winch's Current Limit and used as its Goal Current; its stall tension "
            f"(torque constant × current / spool radius) at most {STALL_TENSION_CEILING_RATIO:g} × "
            "`force_ceiling_n`",
        )
    )
    stale_timeout_s: float = field(
        default=0.2,
        metadata=number(
            0.005,
            10.0,
            unit="s",
            default_doc="5 sample periods of the cell's rate, at least 0.2 (0.2 without a rate)",
            doc="without a valid load-cell sample; at least 3 sample periods of the cell's rate "
            "(`rig check` at the measured rate; `rig run`, also `--dry-run`, at `loadcell.rate_hz`)",
        ),
    )
    max_winch_travel_rev: float = field(default=20.0, metadata=number(0.1, 255.0, unit="rev"))
    zero_tolerance_n: float = field(
        default=2.0,
        metadata=number(
            0.01,
            50.0,
            unit="N",
            doc="the load cell's reading at connect and each trial's tare must be within this of its "
            "calibrated zero (else exit 1: the line may be loaded)",
        ),
    )
    direction_check_rev: float = field(
        default=0.25,
        metadata=number(
            0.02,
            0.5,
            unit="rev",
            doc="every ramp stops the run (exit 1) when the winch has reeled in this far with the tension "
            "risen less than `zero_tolerance_n`: a winch turning the wrong way (`reel_direction`) or a "
            "line off its drum; the nominal line stiffness must give at least 1.5 × `zero_tolerance_n` "
            "over it",
        ),
    )
    max_loaded_after_slip_s: float = field(
        default=2.0,
        metadata=number(
            0.1,
            60.0,
            unit="s",
            doc="after a slip the line is released before anything waits; from the slip's detection to "
            "the cell reading the line slack should take at most this (a longer one is warned about); "
            "`ramp.hold_after_slip_s` must be shorter",
        ),
    )
    recovery_grace_s: float = field(
        default=DEFAULT_RECOVERY_GRACE_S,
        metadata=number(
            0.1,
            60.0,
            unit="s",
            doc="after a device fault in a trial and the release of the line, how long the rig has to "
            "answer healthily again (every servo without a hardware error, the winch at its zero, fresh "
            "load-cell samples) before the run stops (exit 1); a cell whose board resets when its port "
            "reopens needs its boot time",
        ),
    )


@dataclass(frozen=True, kw_only=True)
class ArticleConfig:
    """The test article: geometry in the link-file format (straight configuration) and joint radius."""

    joint_radius_m: float = field(
        metadata=number(0.0001, 0.1, unit="m", doc="only converts capacity to μs·δ0")
    )
    segment_lengths_m: tuple[float, ...] = field(
        metadata=numbers(0.001, 1.0, max_length=MAX_JOINTS, unit="m", doc="L_i; its length is J")
    )
    point_m: tuple[float, float, float] = field(
        metadata=numbers(
            -10.0, 10.0, length=3, unit="m", within="load", doc="acting point Q in the tip frame"
        )
    )
    direction: tuple[float, float, float] = field(
        metadata=numbers(
            -1000.0, 1000.0, length=3, within="load", doc="line direction in the base frame, length ≥ 1e−6"
        )
    )
    g: float = field(default=PAPER_G_M_S2, metadata=number(0.1, 100.0, unit="m/s²"))

    @property
    def joint_count(self) -> int:
        """Number of joints J (components are J + 1, the base included)."""
        return len(self.segment_lengths_m)


@dataclass(frozen=True, kw_only=True)
class ConfigurationConfig:
    """Where the measured link configuration comes from (`configuration:`; docs/formats.md)."""

    source: ConfigurationSourceKind | None = field(
        default=None,
        metadata=choice(
            ConfigurationSourceKind,
            default_doc="`simulator` on a simulated rig, `command` on hardware",
            doc="`command`: nothing is measured, the commanded angles stand in",
        ),
    )
    file: Path | None = field(
        default=None,
        metadata=custom(
            default_doc="none",
            allowed_doc="a CSV or YAML file of measured angles per configuration (the format: "
            '"Measured configurations" below), relative to the config; required with `source: file`',
        ),
    )
    camera: Path | None = field(
        default=None,
        metadata=custom(
            default_doc="none",
            allowed_doc="the camera calibration (OpenCV FileStorage YAML), relative to the config; "
            "required with `source: camera`",
        ),
    )
    markers: Path | None = field(
        default=None,
        metadata=custom(
            default_doc="none",
            allowed_doc="the marker map, relative to the config; required with `source: camera`",
        ),
    )
    device: int = field(default=0, metadata=integer(0, 63, doc="the camera's device index"))


@dataclass(frozen=True, kw_only=True)
class BendingConfig:
    """The bending fixture's forks (`bending:`): how a bender's shaft turns into fork travel."""

    pinion_radius_m: float = field(
        default=0.01,
        metadata=number(0.001, 0.1, unit="m", doc="fork travel per rad of bender shaft (rack and pinion)"),
    )


def configuration_source_kind(config: RigConfig) -> ConfigurationSourceKind:
    """The configuration source a rig config selects (its default depends on the rig's kind)."""
    chosen = config.configuration.source
    if chosen is not None:
        return chosen
    return (
        ConfigurationSourceKind.SIMULATOR
        if config.kind == RigKind.SIMULATED
        else ConfigurationSourceKind.COMMAND
    )


# The simulated cell's rate, declared once for both of its readers: this module (a simulated rig's
# `loadcell.rate_hz` defaults to it) and `rig.sim.settings.SimulationConfig` (the simulator's cell).
SIMULATED_LOADCELL_RATE_HZ = 1000.0
SIMULATED_LOADCELL_RATE_FIELD = number(10.0, 2000.0, unit="Hz")


@dataclass(frozen=True)
class SimulationSection:
    """A rig config's `simulation:` section as written (`rig.sim.settings` parses it), and its cell's rate.

    `source` is the file's name as the config was loaded with it, for the parser's messages.
    """

    data: Mapping[str, Any] = field(hash=False)
    source: str
    loadcell_rate_hz: float = field(
        default=SIMULATED_LOADCELL_RATE_HZ, metadata=SIMULATED_LOADCELL_RATE_FIELD
    )


@dataclass(frozen=True, kw_only=True)
class RigConfig:
    """A validated rig config."""

    source: Path
    text: str
    name: str = field(metadata=custom(default_doc="the file name without extension", allowed_doc="text"))
    kind: RigKind = field(metadata=choice(RigKind))
    spool_radius_m: float = field(
        metadata=number(0.001, 0.2, unit="m", doc="tension = winch torque / radius")
    )
    reel_direction: int = field(
        default=1,
        metadata=custom(
            allowed_doc="1 or -1",
            doc="the sign of the winch's position change that reels line in (-1: a drum wound the "
            "other way); every winch goal is computed with it",
        ),
    )
    line_stiffness_n_per_m: float = field(
        default=200.0,
        metadata=number(
            1.0,
            1e7,
            unit="N/m",
            doc="nominal; used for plans and timeouts (200: about a metre of thin nylon line); "
            "`rig check --move` measures it",
        ),
    )
    servos: ServoBusConfig = field(metadata=section())
    loadcell: LoadCellConfig = field(metadata=section())
    article: ArticleConfig = field(metadata=section())
    limits: RigLimits = field(metadata=section())
    # Its fields are `rig.sim.settings.SimulationConfig`'s (the docs table lists them).
    simulation: SimulationSection | None = field(default=None, metadata=section(default_doc="none"))
    configuration: ConfigurationConfig = field(
        default_factory=lambda: ConfigurationConfig(), metadata=section(default_doc="see the fields")
    )
    bending: BendingConfig = field(default_factory=lambda: BendingConfig(), metadata=section())

    @property
    def winch_stall_tension_n(self) -> float:
        """The line tension at which the winch stalls at its current limit: its hardware tension cap."""
        limits = self.limits
        return stall_tension_n(self.servos.winch.model, limits.winch_current_limit_a, self.spool_radius_m)

    @property
    def line_n_per_rad(self) -> float:
        """The line's tension per radian the winch reels, at the nominal line stiffness [N/rad]."""
        return self.line_stiffness_n_per_m * self.spool_radius_m

    @property
    def joints_from(self) -> str:
        """Where the link's joint count comes from, for a protocol that lists another count."""
        return f"{self.source} (article.segment_lengths_m: {self.article.joint_count} segments)"

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
            "reel_direction": str(self.reel_direction),
            "joint_radius_m": repr(self.article.joint_radius_m),
            "joints": str(self.article.joint_count),
            "force_ceiling_n": repr(self.limits.force_ceiling_n),
        }


def load_rig_config(path: str | Path | None = None) -> RigConfig:
    """Load and validate a rig config; the built-in simulated rig when `path` is None."""
    p = Path(path) if path is not None else DEFAULT_RIG_CONFIG
    text = read_text_file(p, what="a rig config YAML file")
    config = parse_rig_config(parse_yaml(text, str(p)), source=str(p), text=text, base_dir=p.parent)
    check_tension_cap(config)
    return config


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
    reject_undeclared(top, RigConfig)
    kind = read_field(top, RigConfig, "kind")
    article = read_field(top, RigConfig, "article")
    if math.hypot(*article.direction) < 1e-6:
        raise (
            top.section("article")
            .section("load")
            .error(
                "direction",
                "the load direction is zero; allowed: a 3-vector of length >= 1e-6, each |x| <= 1000",
            )
        )
    simulation = None
    if kind == RigKind.SIMULATED or top.has("simulation"):
        # On a hardware rig the section describes the world `rig sim rig` serves behind the config's
        # ports (its twin); the rig's own commands ignore it.
        # `rig.sim.settings` parses the rest when a command loads the config for a rig.
        sim_sec = top.section("simulation", default={})
        simulation = SimulationSection(
            sim_sec.data, source, read_field(sim_sec, SimulationSection, "loadcell_rate_hz")
        )
    loadcell = _loadcell(top.section("loadcell"), base_dir or Path("."))
    loadcell = _loadcell_rate(top, loadcell, simulation if kind == RigKind.SIMULATED else None)
    values = read_fields(
        top,
        RigConfig,
        given={
            "source": Path(source),
            "text": text,
            "name": top.string("name", default=Path(source).stem),
            "reel_direction": _reel_direction(top),
            "kind": kind,
            "servos": _servo_bus(top.section("servos")),
            "loadcell": loadcell,
            "article": article,
            "simulation": simulation,
            "configuration": _configuration(top, kind, base_dir or Path(".")),
            "bending": _bending(top),
        },
    )
    if loadcell.rate_hz is not None and not top.section("limits").has("stale_timeout_s"):
        values["limits"] = replace(
            values["limits"], stale_timeout_s=default_stale_timeout_s(loadcell.rate_hz)
        )
    config = RigConfig(**values)
    _check_forks(top, config)
    return config


# The stale timeout's default for a cell of known rate: 5 sample periods, at least 0.2 s (so the
# 1000/s default is unchanged). The driver uses the same rule.
MIN_STALE_TIMEOUT_S = 0.2
STALE_SAMPLE_PERIODS = 5


def default_stale_timeout_s(rate_hz: float) -> float:
    """The stale timeout for a cell at `rate_hz`: five sample periods, but at least 0.2 s."""
    return max(MIN_STALE_TIMEOUT_S, STALE_SAMPLE_PERIODS / rate_hz)


# The stale timeout must hold at least this many sample periods, or a run stops between two
# healthy samples (a line lost or late by a period is not a dead cell). The project's choice.
MIN_STALE_SAMPLE_PERIODS = 3


@dataclass(frozen=True)
class StaleTimeoutFit:
    """How many sample periods of a cell at `rate_hz` the stale timeout holds, and whether enough.

    The one rule of `rig check` (at the measured rate) and of the run's limit checks, which
    `rig run --dry-run` prints (at the configured rate).
    """

    stale_timeout_s: float
    rate_hz: float

    @property
    def periods(self) -> float:
        """The stale timeout in sample periods."""
        return self.stale_timeout_s * self.rate_hz

    @property
    def ok(self) -> bool:
        """Whether it holds at least `MIN_STALE_SAMPLE_PERIODS` periods."""
        return self.periods >= MIN_STALE_SAMPLE_PERIODS

    @property
    def least_s(self) -> float:
        """The shortest stale timeout that fits this rate."""
        return MIN_STALE_SAMPLE_PERIODS / self.rate_hz

    def describe(self) -> str:
        """E.g. "limits.stale_timeout_s 0.2 s = 2.0 sample periods at 10.0 samples/s"."""
        return (
            f"limits.stale_timeout_s {self.stale_timeout_s:g} s = {self.periods:.1f} sample periods at "
            f"{self.rate_hz:.1f} samples/s"
        )

    def fix(self) -> str:
        """What to do when it does not fit."""
        return (
            f"raise limits.stale_timeout_s to at least {self.least_s:.2f} s (or leave it out: it then "
            "follows loadcell.rate_hz), or run the cell faster"
        )


def _loadcell_rate(
    top: Section, loadcell: LoadCellConfig, simulation: SimulationSection | None
) -> LoadCellConfig:
    """The cell's rate (left out on a simulated rig: its simulation's), checked against baud and format."""
    sec = top.section("loadcell")
    traits = LOADCELL_FORMAT_TRAITS[loadcell.format]
    rate_hz = loadcell.rate_hz
    if simulation is not None and rate_hz is None:
        # Left out, a simulated cell's rate is its simulation's. Given, it is what the operator
        # believes, and may be wrong as on a real rig: the run and `rig check` compare it with what
        # the simulated cell sends.
        rate_hz = simulation.loadcell_rate_hz
    if rate_hz is None:
        if traits.poll_command is not None:
            raise sec.error(
                "rate_hz", f"required for the polled format {loadcell.format}: its poll rate, 0.1-2000"
            )
        return loadcell
    highest_hz = traits.max_rate_hz(loadcell.baud)
    if rate_hz > highest_hz:
        field_name = "rate_hz" if sec.has("rate_hz") else "baud"
        raise sec.error(
            field_name,
            f"{rate_hz:g} lines/s of {loadcell.format} (up to {traits.max_line_bytes} bytes, 10 bits a byte) "
            f"need {rate_hz * traits.max_line_bytes * UART_BITS_PER_BYTE:.0f} baud, more than baud "
            f"{loadcell.baud} carries; allowed: rate_hz 0.1-{math.floor(highest_hz * 10) / 10:g} at this "
            "baud, or a faster baud",
        )
    return replace(loadcell, rate_hz=rate_hz)


def check_tension_cap(config: RigConfig) -> None:
    """Refuse a winch current limit whose stall tension exceeds the ceiling by more than the allowed ratio.

    Checked for every config a command loads to drive a rig (`load_rig_config`), not for a config
    read back from a log: that describes a run already made (logs from before this check carry
    1.2 A on an 80 N ceiling), and replay must still read its geometry. The order is: software
    ceiling < the winch's stall tension (its hardware cap) <= 1.25 x the ceiling < the line's and
    the load cell's ratings; `rig run` checks separately that the stall tension is at least the
    ramp's `max_force_n`.
    """
    ceiling_n = config.limits.force_ceiling_n
    highest_n = STALL_TENSION_CEILING_RATIO * ceiling_n
    stall_n = config.winch_stall_tension_n
    if stall_n > highest_n:
        model = config.servos.winch.model
        # Rounded down to the mA, so that the advice itself passes.
        advice_a = math.floor(current_for_tension_a(model, highest_n, config.spool_radius_m) * 1000) / 1000
        current_a = config.limits.winch_current_limit_a
        raise ConfigError(
            f"{config.source}: limits.winch_current_limit_a: {current_a:g} A lets the winch ({model}, "
            f"spool radius {config.spool_radius_m:g} m) pull {stall_n:.1f} N at stall, above "
            f"{STALL_TENSION_CEILING_RATIO:g} x limits.force_ceiling_n {ceiling_n:g} N = {highest_n:.1f} N; "
            f"set winch_current_limit_a to at most {advice_a:.3f} A"
        )


def _configuration(top: Section, kind: RigKind, base_dir: Path) -> ConfigurationConfig:
    sec = top.section("configuration", default={})
    reject_undeclared(sec, ConfigurationConfig)
    given: dict[str, Any] = {}
    for key in ("file", "camera", "markers"):
        given[key] = sec.file_path(key, base_dir)
    config = ConfigurationConfig(**read_fields(sec, ConfigurationConfig, given=given))
    source = config.source
    if source == ConfigurationSourceKind.SIMULATOR and kind != RigKind.SIMULATED:
        raise sec.error(
            "source", "simulator needs kind: simulated; allowed on hardware: operator, file, camera, command"
        )
    needs = {ConfigurationSourceKind.FILE: ("file",), ConfigurationSourceKind.CAMERA: ("camera", "markers")}
    for key in needs.get(source, ()) if source is not None else ():
        if given[key] is None:
            raise sec.error(key, f"required with source: {source}")
    return config


def _bending(top: Section) -> BendingConfig:
    sec = top.section("bending", default={})
    reject_undeclared(sec, BendingConfig)
    return BendingConfig(**read_fields(sec, BendingConfig))


def _check_forks(top: Section, config: RigConfig) -> None:
    """Fork components: benders only, each in 1..J, none twice; all benders name one or none does."""
    sec = top.section("servos")
    joints = config.article.joint_count
    benders = config.servos.benders
    named = [s.component for s in benders if s.component is not None]
    for s in config.servos.servos:
        if s.component is not None and s.role != ServoRole.BENDER:
            raise sec.error("ids", f"servo {s.servo_id}: component is for benders only (role {s.role})")
        if s.component is not None and not 1 <= s.component <= joints:
            raise sec.error("ids", f"servo {s.servo_id}: component {s.component}; allowed: 1..{joints}")
    if named and len(named) != len(benders):
        raise sec.error("ids", "either every bender names its component or none does")
    if len(set(named)) != len(named):
        raise sec.error("ids", f"components {sorted(named)}: each component takes at most one fork")


def _reel_direction(top: Section) -> int:
    direction = top.integer("reel_direction", default=1, min_value=-1, max_value=1)
    if direction == 0:
        raise top.error("reel_direction", "0; allowed: 1 or -1")
    return direction


def _servo_bus(sec: Section) -> ServoBusConfig:
    reject_undeclared(sec, ServoBusConfig)
    baud = sec.integer("baud", default=1_000_000)
    if baud not in SERVO_BAUDS:
        raise sec.error("baud", f"{baud} is not a Dynamixel baud rate; allowed: {SERVO_BAUDS}")
    specs: list[ServoSpec] = []
    for i, item in enumerate(sec.sequence("ids", min_length=1, max_length=253)):
        entry = Section(item, sec.source, f"{sec.field('ids')}[{i}]")
        component = (
            entry.integer("component", min_value=1, max_value=MAX_JOINTS) if entry.has("component") else None
        )
        specs.append(ServoSpec(**read_fields(entry, ServoSpec, given={"component": component})))
    ids = [s.servo_id for s in specs]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise sec.error("ids", f"duplicate servo id(s) {duplicates}; each id must appear once")
    winches = [s for s in specs if s.role == ServoRole.WINCH]
    if len(winches) != 1:
        raise sec.error("ids", f"expected exactly one servo with role 'winch', found {len(winches)}")
    if not MOTOR_RATINGS[winches[0].model].current_based_position:
        index = specs.index(winches[0])
        raise sec.error(
            f"ids[{index}].model",
            f"{winches[0].model} has no current-based position control (Operating Mode 5), which the winch "
            f"needs; allowed for the winch: {', '.join(winch_models())}",
        )
    given = {"port": _port(sec), "baud": baud, "servos": tuple(specs)}
    return ServoBusConfig(**read_fields(sec, ServoBusConfig, given=given))


def _port(sec: Section) -> str:
    port = sec.string("port")
    if not 0 < len(port) <= MAX_PORT_CHARS:
        raise sec.error("port", f"{len(port)} characters; allowed: a serial port name of 1-{MAX_PORT_CHARS}")
    return port


def _loadcell(sec: Section, base_dir: Path) -> LoadCellConfig:
    reject_undeclared(sec, LoadCellConfig)
    given = {"port": _port(sec), "calibration_path": sec.file_path("calibration", base_dir)}
    return LoadCellConfig(**read_fields(sec, LoadCellConfig, given=given))


# The load-cell rate a rig config that names none is taken to stream at (the detector's tuning rate).
DEFAULT_LOADCELL_RATE_HZ = 1000.0


def nominal_loadcell_rate_hz(config: RigConfig) -> float:
    """The sample rate the run expects of the load cell [Hz].

    `loadcell.rate_hz`, else the simulated cell's rate, else `DEFAULT_LOADCELL_RATE_HZ`.
    """
    if config.loadcell.rate_hz is not None:
        return config.loadcell.rate_hz
    if config.simulation is not None and config.kind == RigKind.SIMULATED:
        return config.simulation.loadcell_rate_hz
    return DEFAULT_LOADCELL_RATE_HZ
