"""Protocol files: what a run does, validated and expanded into a trial plan before anything moves.

A protocol (YAML, `format: rig-protocol/1`, documented in `protocols/README.md`) names the slip
detector settings, the ramp, protocol limits, and a list of blocks. A block is a joint-estimation
series (distances x repeats, optionally shuffled; or `design: adaptive`, whose distances the
planner `model.design` chooses one trial at a time, see `AdaptiveBlock`) or a link-validation
series (planar configurations). Each trial of a block runs the same template of steps (prompt, tare, bend,
measure, ramp_until_slip, unload, reset, pause). Expansion is deterministic for a given seed, so a
resumed run sees the same plan.
"""

from __future__ import annotations

import math
import random
import re
import string
from dataclasses import dataclass
from pathlib import Path
from typing import Any, assert_never

from model.design import (
    DEFAULT_MIN_SPREAD_FRACTION,
    DEFAULT_STARTUP_TRIALS,
    DEFAULT_STOP_SCALE_CONFIDENCE,
    DesignSettings,
)
from model.estimators import DEFAULT_ESTIMATOR, ESTIMATOR_NAMES, EstimatorName, check_estimator
from rig.errors import ConfigError
from rig.files import parse_yaml, read_text_file
from rig.validate import Section
from rig.vocabulary import StepKind, TrialKind

PROTOCOL_FORMAT = "rig-protocol/1"
DESIGNS = ("fixed", "adaptive")
# The keys of each joint-estimation design (docs/formats.md §1): the other design's are refused by name.
FIXED_KEYS = ("distances_m", "repeats", "shuffle")
ADAPTIVE_KEYS = (
    "distance_range_m",
    "distance_count",
    "target_half_width_rel",
    "max_trials",
    "min_trials",
    "startup_trials",
    "min_spread_fraction",
    "max_force_fraction",
    "stop_scale_confidence",
    "estimator",
)
DEFAULT_MAX_FORCE_FRACTION = 0.8
DEFAULT_STEPS: dict[TrialKind, tuple[StepKind, ...]] = {
    TrialKind.JOINT_ESTIMATION: (
        StepKind.PROMPT, StepKind.TARE, StepKind.RAMP_UNTIL_SLIP, StepKind.UNLOAD, StepKind.PAUSE
    ),
    TrialKind.LINK_VALIDATION: (
        StepKind.BEND, StepKind.MEASURE, StepKind.TARE, StepKind.RAMP_UNTIL_SLIP, StepKind.UNLOAD,
        StepKind.RESET, StepKind.PAUSE,
    ),
}  # fmt: skip
# Steps that move or read the bending fixture: only a link-validation trial has them.
LINK_ONLY_STEPS = frozenset({StepKind.BEND, StepKind.RESET, StepKind.MEASURE})
# Size limits (docs/formats.md §1): generous for any real protocol, small enough that a hostile
# file cannot make the plan take minutes or gigabytes.
MAX_BLOCKS = 100
MAX_STEPS = 50
MAX_ITEMS = 1000  # distances or configurations in one block
MAX_TRIALS = 10_000
MAX_JOINTS = 100  # when the rig config is not known yet
MAX_TEXT_CHARS = 1000  # a prompt text
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")  # becomes part of run ids and file names
PROMPT_FIELDS = ("distance_m", "joint", "configuration", "trial", "repeat")
# A format spec of at most 2-digit width and precision (no nested fields: a width of 10**9 is a hang).
_PROMPT_SPEC = re.compile(r"(.?[<>=^])?[+\- ]?#?0?\d{0,2}[,_]?(\.\d{1,2})?[bcdeEfFgGnosxX%]?")
DEFAULT_PROMPTS = {
    TrialKind.JOINT_ESTIMATION: "Hang the hook at {distance_m:.3f} m from joint {joint}, then confirm.",
    TrialKind.LINK_VALIDATION: (
        "Check configuration {configuration} is set and the line is free, then confirm."
    ),
}


@dataclass(frozen=True)
class RampSettings:
    """How the winch loads the line: fast to a fraction of the predicted slip load, then slow."""

    fast_speed_rad_s: float
    slow_speed_rad_s: float
    fast_until_fraction: float
    max_force_n: float
    unload_speed_rad_s: float
    hold_after_slip_s: float


@dataclass(frozen=True)
class StepSpec:
    """One step of a trial's template."""

    kind: StepKind
    text: str | None = None  # prompt text template
    duration_s: float = 0.0  # pause length, tare settle time


@dataclass(frozen=True)
class TrialPlan:
    """One planned trial; `trial_id` is its position in the whole run (1-based)."""

    trial_id: int
    block: int
    kind: TrialKind
    repeat: int
    steps: tuple[StepSpec, ...]
    joint: int | None = None  # joint under test (joint estimation)
    distance_m: float | None = None
    joint_angles_rad: tuple[float, ...] | None = None
    configuration_index: int | None = None

    def prompt_text(self, template: str) -> str:
        """The operator prompt for this trial with its fields filled in."""
        return template.format(
            distance_m=self.distance_m if self.distance_m is not None else math.nan,
            joint=self.joint,
            configuration=self.configuration_index,
            trial=self.trial_id,
            repeat=self.repeat,
        )


@dataclass(frozen=True)
class AdaptiveBlock:
    """A joint-estimation block with `design: adaptive`: the planner chooses each trial's distance.

    It owns the trial ids `trial_ids` (its budget, `design.max_trials`) whether or not it uses them
    all, so the blocks after it keep their ids. A trial's distance is never chosen where its
    predicted slip force exceeds `max_force_fraction` of `max_force_n` (the ramp's, below the ceiling).
    """

    block: int
    first_trial_id: int
    joint: int
    steps: tuple[StepSpec, ...]
    design: DesignSettings
    max_force_fraction: float
    kind: TrialKind = TrialKind.JOINT_ESTIMATION

    @property
    def trial_ids(self) -> range:
        """The ids this block may use, in order."""
        return range(self.first_trial_id, self.first_trial_id + self.design.max_trials)

    def trial(self, trial_id: int, distance_m: float, repeat: int) -> TrialPlan:
        """The plan of one of this block's trials at the distance the planner chose."""
        if trial_id not in self.trial_ids:
            raise ValueError(f"trial {trial_id} is outside block {self.block}'s ids {self.trial_ids}")
        return TrialPlan(
            trial_id=trial_id,
            block=self.block,
            kind=self.kind,
            repeat=repeat,
            steps=self.steps,
            joint=self.joint,
            distance_m=distance_m,
        )


@dataclass(frozen=True)
class Protocol:
    """A validated protocol and its expanded trial plan (fixed trials; adaptive blocks apart)."""

    source: Path
    text: str
    name: str
    description: str
    detector: dict[str, float | None]
    ramp: RampSettings
    force_ceiling_n: float | None
    step_timeout_margin_s: float
    control_period_s: float
    estimates_from: str | None  # "run" (earlier block of this protocol) or a file path
    trials: tuple[TrialPlan, ...]  # the fixed blocks' trials
    adaptive: tuple[AdaptiveBlock, ...] = ()
    estimator: EstimatorName = DEFAULT_ESTIMATOR  # of k, for the run's estimate (docs/model.md §4.2)

    @property
    def kinds(self) -> set[TrialKind]:
        """The trial kinds the plan contains."""
        return {t.kind for t in self.trials} | {b.kind for b in self.adaptive}

    @property
    def schedule(self) -> tuple[TrialPlan | AdaptiveBlock, ...]:
        """Fixed trials and adaptive blocks in the order they run."""
        items: list[TrialPlan | AdaptiveBlock] = [*self.trials, *self.adaptive]
        return tuple(
            sorted(items, key=lambda i: i.trial_id if isinstance(i, TrialPlan) else i.first_trial_id)
        )

    @property
    def planned_trial_ids(self) -> list[int]:
        """Every trial id the run may use: the fixed trials' and each adaptive block's budget."""
        ids = [t.trial_id for t in self.trials] + [i for b in self.adaptive for i in b.trial_ids]
        return sorted(ids)

    def as_metadata(self) -> dict[str, str]:
        """A flat str->str summary for the MCAP `protocol` metadata record."""
        return {
            "name": self.name,
            "source": str(self.source),
            "format": PROTOCOL_FORMAT,
            "trials": str(len(self.planned_trial_ids)),
            "kinds": ",".join(sorted(self.kinds)),
            "detector": ",".join(f"{k}={v!r}" for k, v in self.detector.items()),
            "control_period_s": repr(self.control_period_s),
            "estimator": self.estimator,
        }


def load_protocol(path: str | Path, *, seed: int = 0, joint_count: int | None = None) -> Protocol:
    """Load, validate and expand a protocol file; `seed` drives shuffling."""
    p = Path(path)
    text = read_text_file(p, what="a protocol YAML file")
    return parse_protocol(
        parse_yaml(text, str(p)),
        source=str(p),
        text=text,
        seed=seed,
        joint_count=joint_count,
        base_dir=p.parent,
    )


def parse_protocol(
    data: Any,
    *,
    source: str,
    text: str = "",
    seed: int = 0,
    joint_count: int | None = None,
    base_dir: Path | None = None,
) -> Protocol:
    """Validate a parsed protocol mapping and expand its blocks into trials."""
    top = Section(data, source)
    top.reject_unknown(
        [
            "format",
            "name",
            "description",
            "estimator",
            "detector",
            "ramp",
            "limits",
            "control_period_s",
            "blocks",
        ]
    )
    estimator = check_estimator(top.string("estimator", default=DEFAULT_ESTIMATOR, choices=ESTIMATOR_NAMES))
    fmt = top.string("format")
    if fmt != PROTOCOL_FORMAT:
        raise top.error("format", f"'{fmt}' is not supported; allowed: {PROTOCOL_FORMAT}")
    detector = _detector(top.section("detector", default={}))
    ramp = _ramp(top.section("ramp", default={}))
    limits = top.section("limits", default={})
    limits.reject_unknown(["force_ceiling_n", "step_timeout_margin_s"])
    ceiling = limits.number("force_ceiling_n", default=None, min_value=0.1, max_value=500.0)
    if ceiling is not None and ramp.max_force_n >= ceiling:
        raise top.error(
            "ramp.max_force_n", f"{ramp.max_force_n} must be below limits.force_ceiling_n ({ceiling})"
        )
    rng = random.Random(seed)
    trials: list[TrialPlan] = []
    adaptive: list[AdaptiveBlock] = []
    used = 0  # trial ids given out so far (an adaptive block takes its whole budget)
    estimates_from: str | None = None
    name = top.string("name", default=Path(source).stem)
    if top.has("name") and not NAME_PATTERN.fullmatch(name):
        raise top.error(
            "name", f"{name!r:.70}; allowed: 1-64 letters, digits, '.', '_', '-' (it names the run's files)"
        )
    blocks = top.sequence("blocks", min_length=1, max_length=MAX_BLOCKS)
    for b, raw_block in enumerate(blocks):
        block = Section(raw_block, source, f"blocks[{b}]")
        kind = TrialKind(block.string("kind", choices=tuple(TrialKind)))
        if kind == TrialKind.JOINT_ESTIMATION and block.has("design"):
            design = block.string("design", choices=DESIGNS)
        else:
            design = "fixed"
        if design == "adaptive":
            chosen = _adaptive_block(block, b, used, ramp, joint_count, estimator)
            if used + chosen.design.max_trials > MAX_TRIALS:
                raise block.error(
                    "max_trials",
                    f"the protocol would have more than {MAX_TRIALS} trials; allowed: at most {MAX_TRIALS}",
                )
            _check_prompts(block, chosen.trial(chosen.first_trial_id, chosen.design.distance_min_m, 1))
            adaptive.append(chosen)
            used += chosen.design.max_trials
            continue
        match kind:
            case TrialKind.JOINT_ESTIMATION:
                new = _joint_estimation_block(block, b, used, rng, joint_count)
            case TrialKind.LINK_VALIDATION:
                new = _link_validation_block(block, b, used, joint_count)
            case _:
                assert_never(kind)
        if used + len(new) > MAX_TRIALS:
            raise block.error(
                "repeats",
                f"the protocol would have more than {MAX_TRIALS} trials; allowed: at most {MAX_TRIALS}",
            )
        _check_prompts(block, new[0])
        trials += new
        used += len(new)
        if kind == TrialKind.LINK_VALIDATION:
            source_of_estimates = block.string("estimates_from", default="run")
            if source_of_estimates == "run":
                if not adaptive and not any(t.kind == TrialKind.JOINT_ESTIMATION for t in trials):
                    raise block.error(
                        "estimates_from",
                        "'run' needs a joint_estimation block earlier in this protocol; "
                        "allowed: 'run' or the path of an estimates JSON file",
                    )
            else:
                path = (base_dir or Path(".")) / source_of_estimates
                if not _is_file(path):
                    raise block.error(
                        "estimates_from", f"file {path} not found; allowed: 'run' or a JSON file"
                    )
                source_of_estimates = str(path)
            if estimates_from not in (None, source_of_estimates):
                raise block.error("estimates_from", "all link_validation blocks must use the same estimates")
            estimates_from = source_of_estimates
    return Protocol(
        source=Path(source),
        text=text,
        name=name,
        description=top.string("description", default=""),
        detector=detector,
        ramp=ramp,
        force_ceiling_n=ceiling,
        step_timeout_margin_s=limits.number(
            "step_timeout_margin_s", default=5.0, min_value=0.1, max_value=600
        ),
        control_period_s=top.number("control_period_s", default=0.02, min_value=0.001, max_value=0.1),
        estimates_from=estimates_from,
        trials=tuple(trials),
        adaptive=tuple(adaptive),
        estimator=estimator,
    )


def _detector(sec: Section) -> dict[str, float | None]:
    """Detector settings, validated by the model's own parameter type."""
    from model.slip_detector import DetectorParams

    for key, value in sec.data.items():
        if isinstance(value, int) and abs(value) > 1e300:  # beyond the float range
            digits = int(value.bit_length() * math.log10(2)) + 1
            raise sec.error(
                str(key), f"an integer of {digits} digits is out of range; allowed: docs/model.md §7"
            )
    try:
        params = DetectorParams.from_mapping(dict(sec.data), source=f"{sec.source}: detector")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    return dict(params.to_mapping())


def _ramp(sec: Section) -> RampSettings:
    sec.reject_unknown(
        [
            "fast_speed_rad_s",
            "slow_speed_rad_s",
            "fast_until_fraction",
            "max_force_n",
            "unload_speed_rad_s",
            "hold_after_slip_s",
        ]
    )
    fast = sec.number("fast_speed_rad_s", default=1.0, min_value=0.001, max_value=20.0)
    slow = sec.number("slow_speed_rad_s", default=0.1, min_value=0.001, max_value=20.0)
    if slow > fast:
        raise sec.error("slow_speed_rad_s", f"{slow} must not exceed fast_speed_rad_s ({fast})")
    return RampSettings(
        fast_speed_rad_s=fast,
        slow_speed_rad_s=slow,
        fast_until_fraction=sec.number("fast_until_fraction", default=0.7, min_value=0.0, max_value=0.95),
        max_force_n=sec.number("max_force_n", default=40.0, min_value=0.1, max_value=500.0),
        unload_speed_rad_s=sec.number("unload_speed_rad_s", default=2.0, min_value=0.001, max_value=20.0),
        hold_after_slip_s=sec.number("hold_after_slip_s", default=0.2, min_value=0.0, max_value=10.0),
    )


def _steps(block: Section, kind: TrialKind) -> tuple[StepSpec, ...]:
    raw = block.sequence("steps", default=list(DEFAULT_STEPS[kind]), min_length=1, max_length=MAX_STEPS)
    steps: list[StepSpec] = []
    for i, item in enumerate(raw):
        if isinstance(item, str):
            name, options = item, dict[str, Any]()
        elif isinstance(item, dict) and len(item) == 1:
            name, options = next(iter(item.items()))
            options = {} if options is None else options
        else:
            raise block.error(f"steps[{i}]", "expected a step name or a one-key mapping {name: options}")
        field = f"steps[{i}]"
        if name not in tuple(StepKind):
            raise block.error(field, f"unknown step '{name}'; allowed: {', '.join(StepKind)}")
        step = StepKind(name)
        if step in LINK_ONLY_STEPS and kind != TrialKind.LINK_VALIDATION:
            raise block.error(field, f"step '{name}' needs kind: link_validation")
        steps.append(_step(step, Section(options, block.source, block.field(field)), kind))
    names = [s.kind for s in steps]
    if names.count(StepKind.RAMP_UNTIL_SLIP) != 1:
        raise block.error("steps", "exactly one 'ramp_until_slip' step is required per trial")
    if StepKind.UNLOAD not in names[names.index(StepKind.RAMP_UNTIL_SLIP) :]:
        raise block.error(
            "steps", "an 'unload' step must follow 'ramp_until_slip' (the line must be released)"
        )
    return tuple(steps)


def _step(step: StepKind, opts: Section, kind: TrialKind) -> StepSpec:
    """One step of a template with its options (each kind allows its own, the others none)."""
    match step:
        case StepKind.PROMPT:
            opts.reject_unknown(["text"])
            return StepSpec(step, text=_prompt_text(opts, DEFAULT_PROMPTS[kind]))
        case StepKind.PAUSE:
            opts.reject_unknown(["duration_s"])
            return StepSpec(
                step, duration_s=opts.number("duration_s", default=0.5, min_value=0.0, max_value=3600.0)
            )
        case StepKind.TARE:
            opts.reject_unknown(["settle_s"])
            return StepSpec(
                step, duration_s=opts.number("settle_s", default=0.5, min_value=0.05, max_value=60.0)
            )
        case StepKind.BEND | StepKind.MEASURE | StepKind.RAMP_UNTIL_SLIP | StepKind.UNLOAD | StepKind.RESET:
            opts.reject_unknown([])
            return StepSpec(step)
        case _:
            assert_never(step)


def _joint_estimation_block(
    block: Section, b: int, offset: int, rng: random.Random, joint_count: int | None
) -> list[TrialPlan]:
    for key in ADAPTIVE_KEYS:
        if block.has(key):
            where = "set it at the protocol's top level, or " if key == "estimator" else ""
            raise block.error(
                key, f"{where}only with design: adaptive; allowed here: distances_m, repeats, shuffle"
            )
    block.reject_unknown(["kind", "design", "joint", *FIXED_KEYS, "steps"])
    joint = block.integer("joint", default=1, min_value=1, max_value=joint_count or MAX_JOINTS)
    distances = block.numbers("distances_m", max_length=MAX_ITEMS, min_value=0.001, max_value=2.0)
    repeats = block.integer("repeats", default=1, min_value=1, max_value=100)
    steps = _steps(block, TrialKind.JOINT_ESTIMATION)
    order = [(d, r) for r in range(1, repeats + 1) for d in distances]
    if block.boolean("shuffle", default=False):
        rng.shuffle(order)
    return [
        TrialPlan(
            trial_id=offset + i + 1,
            block=b,
            kind=TrialKind.JOINT_ESTIMATION,
            repeat=r,
            steps=steps,
            joint=joint,
            distance_m=d,
        )
        for i, (d, r) in enumerate(order)
    ]


def _adaptive_block(
    block: Section,
    b: int,
    offset: int,
    ramp: RampSettings,
    joint_count: int | None,
    protocol_estimator: EstimatorName,
) -> AdaptiveBlock:
    """A `design: adaptive` joint-estimation block (docs/formats.md §1), validated."""
    for key in FIXED_KEYS:
        if block.has(key):
            raise block.error(
                key,
                "not with design: adaptive (the planner chooses the distances); allowed: distance_range_m",
            )
    block.reject_unknown(["kind", "design", "joint", *ADAPTIVE_KEYS, "steps"])
    joint = block.integer("joint", default=1, min_value=1, max_value=joint_count or MAX_JOINTS)
    lo, hi = block.numbers("distance_range_m", length=2, min_value=0.001, max_value=2.0)
    if not lo < hi:
        raise block.error(
            "distance_range_m", f"[{lo}, {hi}]; allowed: [shortest, longest] with shortest < longest"
        )
    max_trials = block.integer("max_trials", default=24, min_value=2, max_value=MAX_ITEMS)
    min_trials = block.integer("min_trials", default=min(10, max_trials), min_value=2, max_value=max_trials)
    startup = block.integer(
        "startup_trials", default=min(DEFAULT_STARTUP_TRIALS, max_trials), min_value=2, max_value=max_trials
    )
    estimator = block.string("estimator", default=protocol_estimator, choices=ESTIMATOR_NAMES)
    design = DesignSettings(
        distance_min_m=lo,
        distance_max_m=hi,
        distance_count=block.integer("distance_count", default=8, min_value=2, max_value=100),
        target_half_width_rel=block.number(
            "target_half_width_rel", default=0.02, min_value=0.001, max_value=0.5
        ),
        max_trials=max_trials,
        min_trials=min_trials,
        startup_trials=startup,
        min_spread_fraction=block.number(
            "min_spread_fraction", default=DEFAULT_MIN_SPREAD_FRACTION, min_value=0.0, max_value=0.5
        ),
        estimator=check_estimator(estimator),
        stop_scale_confidence=block.number(
            "stop_scale_confidence", default=DEFAULT_STOP_SCALE_CONFIDENCE, min_value=0.0, max_value=0.99
        ),
    )
    fraction = block.number(
        "max_force_fraction", default=DEFAULT_MAX_FORCE_FRACTION, min_value=0.1, max_value=0.95
    )
    return AdaptiveBlock(
        block=b,
        first_trial_id=offset + 1,
        joint=joint,
        steps=_steps(block, TrialKind.JOINT_ESTIMATION),
        design=design,
        max_force_fraction=fraction,
    )


def _link_validation_block(block: Section, b: int, offset: int, joint_count: int | None) -> list[TrialPlan]:
    block.reject_unknown(["kind", "configurations_deg", "repeats", "estimates_from", "steps"])
    repeats = block.integer("repeats", default=1, min_value=1, max_value=100)
    steps = _steps(block, TrialKind.LINK_VALIDATION)
    configs = block.sequence("configurations_deg", min_length=1, max_length=MAX_ITEMS)
    angles: list[tuple[float, ...]] = []
    for c, raw in enumerate(configs):
        entry = Section({"angles": raw}, block.source, f"{block.field('configurations_deg')}[{c}]")
        values = entry.numbers(
            "angles", length=joint_count, max_length=MAX_JOINTS, min_value=-90.0, max_value=90.0
        )
        angles.append(tuple(math.radians(v) for v in values))
    trials: list[TrialPlan] = []
    for c, config in enumerate(angles):
        for r in range(1, repeats + 1):
            trials.append(
                TrialPlan(
                    trial_id=offset + len(trials) + 1,
                    block=b,
                    kind=TrialKind.LINK_VALIDATION,
                    repeat=r,
                    steps=steps,
                    joint_angles_rad=config,
                    configuration_index=c + 1,
                )
            )
    return trials


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):  # a name too long for the file system, say
        return False


def _prompt_text(opts: Section, default: str) -> str:
    """A prompt template: bounded text whose placeholders are the trial's fields, plainly formatted."""
    text = opts.string("text", default=default)
    allowed = (
        f"at most {MAX_TEXT_CHARS} characters with placeholders {{{'}, {'.join(PROMPT_FIELDS)}}} "
        "and short format specs like {distance_m:.3f} ('{{' and '}}' for braces)"
    )
    if len(text) > MAX_TEXT_CHARS:
        raise opts.error("text", f"{len(text)} characters; allowed: {allowed}")
    try:
        fields = [(f, spec, conv) for _, f, spec, conv in string.Formatter().parse(text) if f is not None]
    except ValueError as exc:
        raise opts.error("text", f"{exc}; allowed: {allowed}") from None
    for field, spec, conversion in fields:
        if field not in PROMPT_FIELDS or conversion is not None or not _PROMPT_SPEC.fullmatch(spec or ""):
            shown = (
                "{" + field + (f"!{conversion}" if conversion else "") + (f":{spec}" if spec else "") + "}"
            )
            raise opts.error("text", f"placeholder {shown!r:.60} is not allowed; allowed: {allowed}")
    return text


def _check_prompts(block: Section, trial: TrialPlan) -> None:
    """Fill the block's prompt templates once, so a spec that does not suit a field fails now, not mid-run."""
    for i, step in enumerate(trial.steps):
        if step.kind == StepKind.PROMPT and step.text is not None:
            try:
                trial.prompt_text(step.text)
            except (ValueError, TypeError) as exc:
                raise block.error(
                    f"steps[{i}]", f"prompt text: {exc}; allowed: format specs that suit the field"
                ) from None
