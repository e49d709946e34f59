"""The simulation section of a rig config: a simulated rig's world, or the twin of a hardware rig.

The simulated world's preset, its slip kinds, capacity scatter, load-cell artefacts and injected
faults. On `kind: hardware` only `rig sim rig` reads it (rig/sim/twin.py). Users' docs in
protocols/README.md.

`rig.inputs.rig_config` keeps the section as written (`SimulationSection`); `simulation_settings` parses it
and checks it against the rest of the config. Every command that loads a config for a rig does so
through `load_checked_rig_config` (or `check_simulation`), so that a bad section fails there, before
anything starts, naming the file and the field.

Each settings field is declared once on its dataclass (`model.field_spec`): its bounds, default and
doc drive `parse_simulation`, the refusal of unknown keys, the dataclasses' own checks and the docs
table (`tools.config_docs`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from model.field_spec import (
    FieldType,
    choice,
    custom,
    declared_fields,
    flag,
    integer,
    number,
    numbers,
    section,
)
from rig.errors import ConfigError
from rig.inputs.rig_config import (
    SIMULATED_LOADCELL_RATE_FIELD,
    SIMULATED_LOADCELL_RATE_HZ,
    RigConfig,
    load_rig_config,
)
from rig.inputs.validate import Section, read_field, read_fields, reject_undeclared
from rig.sim.kinds import (
    FaultDevice,
    FaultKind,
    HostFaultKind,
    LoadCellFaultKind,
    LoggerFaultKind,
    ServoFaultKind,
    SlipKind,
)
from rig.vocabulary import RigKind, ServoModel

SIM_PRESETS = ("link1", "link2")

# Which faults each simulated device can be given (`simulation.faults:`, docs in protocols/README.md).
FaultKindEnum = type[ServoFaultKind] | type[LoadCellFaultKind] | type[LoggerFaultKind] | type[HostFaultKind]
FAULT_KINDS: dict[FaultDevice, FaultKindEnum] = {
    FaultDevice.SERVOS: ServoFaultKind,
    FaultDevice.WINCH: ServoFaultKind,
    FaultDevice.BENDER: ServoFaultKind,
    FaultDevice.LOADCELL: LoadCellFaultKind,
    FaultDevice.LOGGER: LoggerFaultKind,
    FaultDevice.HOST: HostFaultKind,
}
# Kinds that happen per reply or per line with a probability (`rate`); the others happen at a time.
RATE_FAULT_KINDS: frozenset[FaultKind] = frozenset(
    {
        ServoFaultKind.DROP,
        ServoFaultKind.CORRUPT,
        ServoFaultKind.DELAY,
        LoadCellFaultKind.GARBLE,
        LoadCellFaultKind.CHECKSUM,
    }
)


@dataclass(frozen=True)
class FaultConfig:
    """One fault to inject into the simulated rig: a rate (per reply or line) or an event at `at_s`.

    `at_s` counts from the start of the invocation's virtual clock; `duration_s` None means to the
    end of the run. A `logger` `write_error` fails the log's writes once it holds `after_bytes`.
    Which fields an entry needs depends on its kind (`parse_fault`).
    """

    device: FaultDevice = field(metadata=choice(FaultDevice))
    kind: FaultKind = field(metadata=custom(doc="one of the device's fault kinds"))
    rate: float | None = field(default=None, metadata=number(0.0, 1.0))
    at_s: float | None = field(default=None, metadata=number(0.0, 1e6, unit="s"))
    duration_s: float | None = field(default=None, metadata=number(0.0, 1e6, lo_open=True, unit="s"))
    delay_ms: float | None = field(default=None, metadata=number(0.0, 10_000.0, unit="ms"))
    after_bytes: int | None = field(default=None, metadata=integer(1, 2**40))


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

    probabilities: tuple[float, ...] = field(
        default=(1.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        metadata=custom(key="mix", doc="probability of each slip kind, summing to 1"),
    )
    small_drop_fraction: tuple[float, float] = field(
        default=(0.03, 0.15), metadata=numbers(0.005, 0.5, length=2)
    )
    creep_duration_s: tuple[float, float] = field(default=(0.05, 2.0), metadata=numbers(0.01, 10.0, length=2))
    creep_drop_fraction: tuple[float, float] = field(
        default=(0.02, 0.10), metadata=numbers(0.001, 0.5, length=2)
    )
    stick_slip_drops: tuple[float, float] = field(default=(2, 5), metadata=numbers(2, 20, length=2))
    stick_slip_drop_fraction: tuple[float, float] = field(
        default=(0.03, 0.10), metadata=numbers(0.005, 0.5, length=2)
    )
    stick_slip_dwell_s: tuple[float, float] = field(
        default=(0.01, 0.04), metadata=numbers(0.002, 1.0, length=2)
    )
    other_joint_load_fraction: tuple[float, float] = field(
        default=(0.5, 0.9), metadata=numbers(0.05, 0.99, length=2)
    )
    other_joint_drop_fraction: tuple[float, float] = field(
        default=(0.05, 0.20), metadata=numbers(0.005, 0.9, length=2)
    )
    other_joint_report_probability: float = field(default=1.0, metadata=number(0.0, 1.0))
    # Slip loads beyond any force ceiling a rig config allows (500 N).
    no_slip_capacity_factor: float = field(default=100.0, metadata=number(1.0, 1000.0, lo_open=True))

    def __post_init__(self) -> None:
        """Check ranges; a `ValueError` names the field and what is allowed."""
        p = self.probabilities
        if len(p) != len(SlipKind) or min(p) < 0 or abs(sum(p) - 1.0) > 1e-9:
            raise ValueError(f"slip kind probabilities {p}; allowed: {len(SlipKind)} numbers >= 0, sum 1")
        for name, lo, hi in slip_ranges():
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


def slip_ranges() -> list[tuple[str, float, float]]:
    """The slip-kind parameters drawn from a [lowest, highest] range, with their declared bounds."""
    return [
        (d.name, float(d.spec.bounds.lo or 0.0), float(d.spec.bounds.hi or 0.0))
        for d in declared_fields(SlipKindMix)
        if d.spec.type == FieldType.NUMBERS
    ]


# Shapes of the trial-to-trial scatter of a joint's capacity, stated for the slip mass m it gives:
# sd(m)^2 = a^2 + (b m)^2 with a = 0 (multiplicative), b = 0 (additive) or both (mixed).
SCATTER_SHAPES = ("multiplicative", "additive", "mixed")
MAX_SCATTER_A_KG = 10.0
MAX_SCATTER_B = 0.5


@dataclass(frozen=True)
class CapacityScatter:
    """The scatter shape (`simulation.scatter:`); `b` None keeps the preset's relative sd."""

    shape: str = field(default="multiplicative", metadata=choice(SCATTER_SHAPES))
    # additive sd of the slip mass [kg]; required by (and only for) shapes additive and mixed
    a_kg: float = field(default=0.0, metadata=number(0.0, MAX_SCATTER_A_KG, lo_open=True, unit="kg"))
    # relative sd of the slip mass (shapes multiplicative and mixed)
    b: float | None = field(default=None, metadata=number(0.0, MAX_SCATTER_B))

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

    noise_scale: float = field(default=1.0, metadata=number(0.0, 100.0))
    drift_n_per_s: float = field(default=0.0, metadata=number(-10.0, 10.0, unit="N/s"))
    wander_n_per_sqrt_s: float = field(default=0.0, metadata=number(0.0, 10.0, unit="N/√s"))
    spike_rate_per_s: float = field(default=0.0, metadata=number(0.0, 100.0, unit="1/s"))
    spike_n: float = field(default=0.0, metadata=number(0.0, 100.0, unit="N"))
    hum_n: float = field(default=0.0, metadata=number(0.0, 10.0, unit="N"))
    hum_hz: float = field(default=50.0, metadata=number(1.0, 500.0, unit="Hz"))
    gain_creep_fraction: float = field(default=0.0, metadata=number(-0.2, 0.2))
    gain_creep_time_constant_s: float = field(default=60.0, metadata=number(0.1, 1e5, unit="s"))

    def __post_init__(self) -> None:
        """Check ranges (the declared ones); a `ValueError` names the field and what is allowed."""
        for declared in declared_fields(LoadCellArtefacts):
            value = getattr(self, declared.name)
            if not declared.spec.bounds.accepts(value):
                lo, hi = declared.spec.bounds.lo, declared.spec.bounds.hi
                raise ValueError(f"{declared.name} = {value}; allowed: {lo:g}-{hi:g}")

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
class SimulatedCell:
    """A load cell as labs have them, for the simulator (`simulation.loadcell_cell`).

    The bridge: a `capacity_n` cell at 2 mV/V on 5 V excitation gives 10 mV at capacity. An ADC at
    gain 128 on 5 V has a full scale of +-20 mV over 2**23 counts (2.384 nV a count), so its counts
    per newton and its noise in counts follow from the input noise (HX711 datasheet: 50 nV RMS at
    10/s, 90 nV at 80/s). `settling_s`: no conversion after power-up, a reset or a rate change
    until then (HX711: 400 ms at 10/s, 50 ms at 80/s). A polled gauge (`value-unit`) answers with
    its reading in `gauge_unit` to `gauge_decimals`; its own noise is `input_noise_nv` equivalent.
    Figures marked assumed in `SIMULATED_CELLS` are not from a datasheet.
    """

    rate_hz: float
    format: str  # a LoadCellFormatName value
    input_noise_nv: float  # RMS input-referred noise of the converter
    settling_s: float
    capacity_n: float = 49.03  # a 5 kg cell
    full_scale_mv: float = 20.0  # +-0.5 AVDD / gain 128 at 5 V
    adc_bits: int = 24
    bridge_mv_at_capacity: float = 10.0  # 2 mV/V x 5 V
    gauge_unit: str = "lbf"
    gauge_decimals: int = 2
    doc: str = ""

    @property
    def counts_per_n(self) -> float:
        """ADC counts per newton of line tension."""
        nv_per_count = self.full_scale_mv * 1e6 / (1 << (self.adc_bits - 1))
        return self.bridge_mv_at_capacity * 1e6 / self.capacity_n / nv_per_count

    @property
    def noise_counts(self) -> float:
        """RMS noise in counts."""
        nv_per_count = self.full_scale_mv * 1e6 / (1 << (self.adc_bits - 1))
        return self.input_noise_nv / nv_per_count


# `default` is the simulator's own cell (1000/s, 5 mN noise from the preset); the others are the
# cells labs own (issue 21). Scenario rigs for each: protocols/rigs/scenarios/cell-*.yaml.
SIMULATED_CELLS: dict[str, SimulatedCell | None] = {
    "default": None,
    "hx711-10": SimulatedCell(
        10.0, "rig-lc1", 50.0, 0.4, doc="HX711 breakout as sold (RATE to GND): 10/s, 50 nV, settles 400 ms"
    ),
    "hx711-80": SimulatedCell(
        80.0, "rig-lc1", 90.0, 0.05, doc="HX711 with RATE high: 80/s, 90 nV, settles 50 ms"
    ),
    "hx717-320": SimulatedCell(
        320.0,
        "rig-lc1",
        180.0,
        0.0125,
        doc="HX717 or NAU7802 at 320/s; noise (90 nV x sqrt(320/80)) and settling (4 conversions) assumed",
    ),
    "gauge-12": SimulatedCell(
        12.0,
        "value-unit",
        500.0,
        0.0,
        doc="a polled force gauge (Mark-10 style `-18.78 lbF`), polled 12/s, 0.01 lbf display; noise assumed",
    ),
}


@dataclass(frozen=True)
class SimulationConfig:
    """Simulated-world settings (`kind: simulated`, or the twin `rig sim rig` serves of a hardware rig)."""

    preset: str = field(default="link1", metadata=choice(SIM_PRESETS, doc="simulated only"))
    loadcell_rate_hz: float = field(
        default=SIMULATED_LOADCELL_RATE_HZ, metadata=SIMULATED_LOADCELL_RATE_FIELD
    )
    noise_scale: float = field(
        default=1.0, metadata=number(0.0, 10.0, doc="multiplies every noise level of the preset")
    )
    winch_reversed: bool = field(
        default=False,
        metadata=flag(
            doc="the line is wound onto the drum the other way: reeling in lowers the winch's position "
            "(a rig config for it needs `reel_direction: -1`)"
        ),
    )
    initial_tension_n: float = field(
        default=0.0,
        metadata=number(
            0.0,
            500.0,
            unit="N",
            doc="the line's tension when the world starts, as after a stop that could not release it "
            "(0: slack, the preset's reel-in before taut)",
        ),
    )
    servo_supply_v: float = field(
        default=12.0,
        metadata=number(
            0.0, 30.0, unit="V", doc="every emulated servo's Present Input Voltage (`rig check` compares it)"
        ),
    )
    servo_temperature_c: int = field(
        default=30, metadata=integer(0, 120, unit="°C", doc="every emulated servo's Present Temperature")
    )
    servo_firmware: int = field(
        default=48,
        metadata=integer(
            0,
            255,
            doc="every emulated servo's Firmware Version (< 38: no Bus Watchdog; < 45: no Fast Sync Read)",
        ),
    )
    servo_models: tuple[ServoModel, ...] | None = field(
        default=None,
        metadata=custom(
            allowed_doc="one model per configured servo, in `servos.ids` order",
            optional=True,
            default_doc="the configured models",
            doc="the servos actually on the emulated bus: another model at an ID than the config "
            "names is a servo the lab mixed up (`rig check` fails its handshake, naming the fix)",
        ),
    )
    torsion_weak_joint: int | None = field(
        default=None,
        metadata=custom(
            allowed_doc="a joint 1..J whose torsion capacity is below its bending capacity", optional=True
        ),
    )
    faults: tuple[FaultConfig, ...] = field(
        default=(),
        metadata=custom(
            allowed_doc='faults to inject; protocols/README.md "Injected faults"', default_doc="none"
        ),
    )
    slips: SlipKindMix = field(
        default=SlipKindMix(),
        metadata=section(
            default_doc="`{mix: {sudden: 1}}`",
            doc='slip kinds and their probabilities and parameters; protocols/README.md "Scenario rigs"',
            expand_doc=False,
        ),
    )
    scatter: CapacityScatter = field(
        default=CapacityScatter(),
        metadata=section(
            default_doc="`{shape: multiplicative}`",
            doc="capacity scatter: `multiplicative` (b), `additive` (a_kg), `mixed` (both); same section",
            expand_doc=False,
        ),
    )
    loadcell: LoadCellArtefacts = field(
        default=LoadCellArtefacts(),
        metadata=section(
            default_doc="all off",
            doc="load-cell artefacts: noise scale, drift, wander, spikes, hum, gain creep; same section",
            expand_doc=False,
        ),
    )
    # Appended (issue 21): which kind of cell the simulator emulates.
    loadcell_cell: str = field(
        default="default",
        metadata=choice(
            SIMULATED_CELLS,
            doc="the simulated cell: `default` (1000/s, the preset's noise) or a cell labs own, "
            "`hx711-10`, `hx711-80`, `hx717-320`, `gauge-12` (its rate must be `loadcell_rate_hz`)",
        ),
    )
    loadcell_clock_error_ppm: float = field(
        default=0.0,
        metadata=number(
            -50_000.0, 50_000.0, unit="ppm", doc="the cell's clock runs this fast (negative: slow)"
        ),
    )
    loadcell_dtr_reset_s: float = field(
        default=0.0,
        metadata=number(
            0.0,
            10.0,
            unit="s",
            doc="opening the port resets the cell's board (an Arduino's DTR): silent this long, "
            "then its banner",
        ),
    )
    # Appended (issue 21): series compliance, the line stiffness a low-rate cell needs to read
    # slip loads finer than one servo count (docs/hardware.md, "Line compliance").
    spring_stiffness_n_per_m: float | None = field(
        default=None,
        metadata=number(
            1.0,
            1e7,
            unit="N/m",
            optional=True,
            default_doc="none (the preset's 5000 N/m line alone)",
            doc="a spring in series with the simulated line; set the rig's `line_stiffness_n_per_m` "
            "to the series stiffness",
        ),
    )

    @property
    def cell(self) -> SimulatedCell | None:
        """The simulated cell's profile (None: the simulator's default cell)."""
        return SIMULATED_CELLS[self.loadcell_cell]


def parse_simulation(sec: Section, joint_count: int) -> SimulationConfig:
    """`simulation:` of a simulated rig config (`joint_count` J bounds `torsion_weak_joint`)."""
    reject_undeclared(sec, SimulationConfig)
    weak = sec.raw("torsion_weak_joint", default=None)
    if weak is not None:
        weak = sec.integer("torsion_weak_joint", min_value=1, max_value=joint_count)
    servo_models = None
    if sec.has("servo_models"):
        names = [str(m) for m in ServoModel]
        items = sec.sequence("servo_models", min_length=1, max_length=253)
        for i, item in enumerate(items):
            if item not in names:
                raise sec.error(f"servo_models[{i}]", f"{item!r}; allowed: {', '.join(names)}")
        servo_models = tuple(ServoModel(item) for item in items)
    faults = tuple(
        parse_fault(Section(item, sec.source, sec.field("faults") + f"[{i}]"))
        for i, item in enumerate(sec.sequence("faults", default=[]))
    )
    values = read_fields(
        sec,
        SimulationConfig,
        given={
            "torsion_weak_joint": weak,
            "servo_models": servo_models,
            "faults": faults,
            "slips": parse_slips(sec.section("slips", default={})),
            "scatter": parse_scatter(sec.section("scatter", default={})),
        },
    )
    cell = SIMULATED_CELLS[values["loadcell_cell"]]
    if cell is not None and values["loadcell_rate_hz"] != cell.rate_hz:
        raise sec.error(
            "loadcell_rate_hz",
            f"{values['loadcell_rate_hz']:g}; allowed: {cell.rate_hz:g}, the rate of loadcell_cell "
            f"{values['loadcell_cell']}",
        )
    return SimulationConfig(**values)


def parse_slips(sec: Section) -> SlipKindMix:
    """`simulation.slips`: the mix of slip kinds (probabilities summing to 1) and their ranges."""
    defaults = SlipKindMix()
    reject_undeclared(sec, SlipKindMix)
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
    values = read_fields(sec, SlipKindMix, given={"probabilities": probabilities})
    for name, lo, hi in slip_ranges():
        first, last = values[name]
        if first > last:
            raise sec.error(name, f"[{first:g}, {last:g}]; allowed: [lowest, highest] within {lo:g}-{hi:g}")
        if name == "stick_slip_drops" and any(x != int(x) for x in (first, last)):
            raise sec.error(name, f"[{first:g}, {last:g}]; allowed: whole numbers within {lo:g}-{hi:g}")
    return SlipKindMix(**values)


def parse_scatter(sec: Section) -> CapacityScatter:
    """`simulation.scatter`: shape multiplicative (b), additive (a_kg) or mixed (both)."""
    reject_undeclared(sec, CapacityScatter)
    shape = read_field(sec, CapacityScatter, "shape")
    if shape == "multiplicative" and sec.has("a_kg"):
        raise sec.error("a_kg", "only for shape additive or mixed; allowed: remove it, or change the shape")
    if shape == "additive" and sec.has("b"):
        raise sec.error(
            "b", "only for shape multiplicative or mixed; allowed: remove it, or change the shape"
        )
    a_kg = 0.0
    if shape != "multiplicative":
        a_kg = read_field(sec, CapacityScatter, "a_kg", required=True)
    b = read_field(sec, CapacityScatter, "b")
    return CapacityScatter(shape=shape, a_kg=a_kg, b=b)


def parse_fault(sec: Section) -> FaultConfig:
    """One entry of `simulation.faults`: which fields it needs depends on its kind."""
    reject_undeclared(sec, FaultConfig)
    device = read_field(sec, FaultConfig, "device")
    kinds = FAULT_KINDS[device]
    kind: FaultKind = kinds(sec.string("kind", choices=tuple(kinds)))
    if device == FaultDevice.LOGGER:
        return FaultConfig(
            device, kind, after_bytes=read_field(sec, FaultConfig, "after_bytes", required=True)
        )
    if kind in RATE_FAULT_KINDS:
        rate = read_field(sec, FaultConfig, "rate", required=True)
        delay = None
        if kind == ServoFaultKind.DELAY:
            delay = read_field(sec, FaultConfig, "delay_ms", default=50.0)
        return FaultConfig(device, kind, rate=rate, delay_ms=delay)
    at_s = read_field(sec, FaultConfig, "at_s", required=True)
    duration = read_field(sec, FaultConfig, "duration_s", required=device == FaultDevice.HOST)
    return FaultConfig(device, kind, at_s=at_s, duration_s=duration)


def simulation_settings(config: RigConfig) -> SimulationConfig | None:
    """The config's `simulation:` section parsed and checked against the rest (None: it has none).

    A `ConfigError` names the file and the field: a field of the section, `simulation.servo_models`
    (one model per configured servo) or `loadcell.format` (the simulated cell's).
    """
    if config.simulation is None:
        return None
    sec = Section(config.simulation.data, config.simulation.source, "simulation")
    sim = parse_simulation(sec, config.article.joint_count)
    if (
        config.kind == RigKind.SIMULATED
        and sim.cell is not None
        and sim.cell.format != config.loadcell.format
    ):
        raise Section({}, sec.source, "loadcell").error(
            "format",
            f"{config.loadcell.format}; allowed: {sim.cell.format}, the format of simulation.loadcell_cell "
            f"{sim.loadcell_cell}",
        )
    count = len(config.servos.servos)
    if sim.servo_models is not None and len(sim.servo_models) != count:
        raise sec.error(
            "servo_models", f"{len(sim.servo_models)} models; allowed: one per servo of servos.ids ({count})"
        )
    return sim


def check_simulation(config: RigConfig) -> None:
    """Refuse a config whose `simulation:` section is bad (`simulation_settings`'s `ConfigError`)."""
    simulation_settings(config)


def load_checked_rig_config(path: str | Path | None = None) -> RigConfig:
    """`rig.inputs.rig_config.load_rig_config`, with the `simulation:` section checked too."""
    config = load_rig_config(path)
    check_simulation(config)
    return config


def require_simulated(config: RigConfig) -> SimulationConfig:
    """The simulation settings of a simulated rig (a ConfigError for a hardware rig, even with a twin's)."""
    sim = simulation_settings(config) if config.kind == RigKind.SIMULATED else None
    if sim is None:
        raise ConfigError(f"{config.source}: kind: this command needs kind: simulated, got {config.kind}")
    return sim


def simulation_section(config: RigConfig) -> SimulationConfig:
    """The world a config's `simulation:` section describes, of either kind (a hardware rig's twin)."""
    sim = simulation_settings(config)
    if sim is None:
        raise ConfigError(
            f"{config.source}: simulation: missing; allowed: a simulation section (see protocols/README.md)"
        )
    return sim
