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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, assert_never

from model.design import (
    DEFAULT_MIN_SPREAD_FRACTION,
    DEFAULT_STARTUP_TRIALS,
    DEFAULT_STOP_SCALE_CONFIDENCE,
    DesignSettings,
)
from model.field_spec import choice, custom, flag, integer, keys_within, number, numbers, section, top_keys
from model.field_spec import text as text_field
from model.k_estimators import DEFAULT_ESTIMATOR, ESTIMATOR_NAMES, EstimatorName, check_estimator
from model.slip_detector import DetectorParams, params_for_rate
from rig.errors import ConfigError
from rig.inputs.files import parse_yaml, read_text_file
from rig.inputs.validate import Section, read_field, read_fields, reject_undeclared
from rig.vocabulary import StepKind, TrialKind

PROTOCOL_FORMAT = "rig-protocol/1"
DESIGNS = ("fixed", "adaptive")
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
# Steps that move the bending fixture: only a link-validation trial has them. (`measure` may be in a
# joint-estimation template too: with a camera, the configuration before the slip tells which joint moved.)
LINK_ONLY_STEPS = frozenset({StepKind.BEND, StepKind.RESET})
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


# The fields of a block of each kind (docs/formats.md §1), declared for reading and the docs table;
# `_joint_estimation_block`, `_adaptive_block` and `_link_validation_block` make the trials.
_JOINT = custom(default_doc="1", allowed_doc="1..J (J from the rig config, at most 100)")
_STEPS = custom(
    default_doc="see below",
    allowed_doc=f"1-{MAX_STEPS} step names or one-key mappings `{{name: {{options}}}}`",
)


@dataclass(frozen=True, kw_only=True)
class FixedBlockFields:
    """A joint-estimation block with `design: fixed` (the default): distances x repeats."""

    kind: TrialKind = field(metadata=choice(TrialKind))
    design: str = field(
        default="fixed",
        metadata=choice(
            DESIGNS,
            doc="`fixed`: `distances_m` × `repeats`; `adaptive`: the planner chooses every distance "
            "([protocols/README.md](../protocols/README.md#adaptive-design-design-adaptive)); the keys of "
            "kind `fixed` are refused in an `adaptive` block and those of kind `adaptive` in a `fixed` one",
        ),
    )
    joint: int = field(default=1, metadata=_JOINT)
    distances_m: tuple[float, ...] = field(metadata=numbers(0.001, 2.0, max_length=MAX_ITEMS, unit="m"))
    repeats: int = field(default=1, metadata=integer(1, 100))
    shuffle: bool = field(default=False, metadata=flag(doc="shuffled with `rig run --seed`"))
    steps: tuple[str, ...] = field(default=(), metadata=_STEPS)


@dataclass(frozen=True, kw_only=True)
class AdaptiveBlockFields:
    """A joint-estimation block with `design: adaptive`: the planner chooses every distance."""

    kind: TrialKind = field(metadata=choice(TrialKind))
    design: str = field(metadata=choice(DESIGNS))
    joint: int = field(default=1, metadata=_JOINT)
    distance_range_m: tuple[float, float] = field(
        metadata=numbers(0.001, 2.0, length=2, unit="m", doc="[shortest, longest], shortest < longest")
    )
    distance_count: int = field(
        default=8, metadata=integer(2, 100, doc="candidate distances, evenly over the range")
    )
    target_half_width_rel: float = field(
        default=0.02,
        metadata=number(
            0.001,
            0.5,
            doc="stop when the 99 % bound's half-width (with the scatter's scale at its upper "
            "`stop_scale_confidence` limit, if set) is at most this share of k",
        ),
    )
    max_trials: int = field(
        default=24, metadata=integer(2, MAX_ITEMS, doc="the block owns this many trial ids")
    )
    min_trials: int = field(
        default=10, metadata=custom(default_doc="10 (at most `max_trials`)", allowed_doc="2..`max_trials`")
    )
    startup_trials: int = field(
        default=DEFAULT_STARTUP_TRIALS,
        metadata=custom(
            default_doc=f"{DEFAULT_STARTUP_TRIALS} (at most `max_trials`)", allowed_doc="2..`max_trials`"
        ),
    )
    min_spread_fraction: float = field(default=DEFAULT_MIN_SPREAD_FRACTION, metadata=number(0.0, 0.5))
    max_force_fraction: float = field(
        default=DEFAULT_MAX_FORCE_FRACTION,
        metadata=number(0.1, 0.95, doc="a share of `ramp.max_force_n` (and the ceiling)"),
    )
    stop_scale_confidence: float = field(
        default=DEFAULT_STOP_SCALE_CONFIDENCE,
        metadata=number(
            0.0,
            0.99,
            doc="the stop tests the bound with the scatter's scale at this upper confidence limit "
            "(0: the bound as estimated)",
        ),
    )
    estimator: str = field(
        default=DEFAULT_ESTIMATOR, metadata=choice(ESTIMATOR_NAMES, default_doc="the protocol's `estimator`")
    )
    steps: tuple[str, ...] = field(default=(), metadata=_STEPS)


@dataclass(frozen=True, kw_only=True)
class LinkValidationBlockFields:
    """A link-validation block: configurations x repeats, each trial predicted before it runs."""

    kind: TrialKind = field(metadata=choice(TrialKind))
    configurations_deg: tuple[tuple[float, ...], ...] = field(
        metadata=custom(allowed_doc=f"1-{MAX_ITEMS} lists of J joint angles about y, each in [−90, 90]°")
    )
    repeats: int = field(default=1, metadata=integer(1, 100))
    estimates_from: str = field(
        default="run",
        metadata=text_field(
            allowed_doc="`run` (needs an earlier joint_estimation block) or a §5 file, relative to the "
            "protocol; the same in every link_validation block"
        ),
    )
    steps: tuple[str, ...] = field(default=(), metadata=_STEPS)
    bend_tolerance_deg: float = field(
        default=1.0,
        metadata=number(
            0.01,
            10.0,
            unit="°",
            doc="a bent configuration within this of its target (every joint) needs no correction",
        ),
    )
    bend_corrections: int = field(
        default=2,
        metadata=integer(
            0, 10, doc="at most this many corrections after bending by forks (bend, measure, correct)"
        ),
    )


# The keys of each joint-estimation design: the other design's are refused by name.
FIXED_KEYS = tuple(k for k in top_keys(FixedBlockFields) if k not in top_keys(AdaptiveBlockFields))
ADAPTIVE_KEYS = tuple(k for k in top_keys(AdaptiveBlockFields) if k not in top_keys(FixedBlockFields))


@dataclass(frozen=True, kw_only=True)
class RampSettings:
    """How the winch loads the line: fast to a fraction of the predicted slip load, then slow."""

    fast_speed_rad_s: float = field(default=1.0, metadata=number(0.001, 20.0, unit="rad/s"))
    slow_speed_rad_s: float = field(
        default=0.1, metadata=number(0.001, 20.0, unit="rad/s", doc="≤ `fast_speed_rad_s`")
    )
    fast_until_fraction: float = field(
        default=0.7, metadata=number(0.0, 0.95, doc="a share of the predicted slip load")
    )
    max_force_n: float = field(
        default=40.0, metadata=number(0.1, 500.0, unit="N", doc="below `limits.force_ceiling_n`")
    )
    unload_speed_rad_s: float = field(default=2.0, metadata=number(0.001, 20.0, unit="rad/s"))
    hold_after_slip_s: float = field(default=0.2, metadata=number(0.0, 10.0, unit="s"))


# The options of the steps that have any (`steps: [{pause: {duration_s: 1}}]`); the others take none.
@dataclass(frozen=True)
class PromptOptions:
    """`prompt` step options."""

    text: str = field(metadata=custom(doc="the operator prompt"))


@dataclass(frozen=True)
class TareOptions:
    """`tare` step options."""

    settle_s: float = field(default=0.5, metadata=number(0.05, 60.0, unit="s"))


@dataclass(frozen=True)
class PauseOptions:
    """`pause` step options."""

    duration_s: float = field(default=0.5, metadata=number(0.0, 3600.0, unit="s"))


@dataclass(frozen=True)
class NoOptions:
    """The options of a step that takes none."""


STEP_OPTIONS: dict[StepKind, type] = {
    StepKind.PROMPT: PromptOptions,
    StepKind.TARE: TareOptions,
    StepKind.PAUSE: PauseOptions,
}


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
    bend_tolerance_rad: float = math.radians(1.0)  # link validation: reached within this needs no correction
    bend_corrections: int = 2  # link validation: at most this many corrections

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


@dataclass(frozen=True, kw_only=True)
class Protocol:
    """A validated protocol and its expanded trial plan (fixed trials; adaptive blocks apart)."""

    source: Path
    text: str
    format: str = field(metadata=custom(allowed_doc=f"`{PROTOCOL_FORMAT}`"))
    name: str = field(
        metadata=custom(
            default_doc="the file name without extension",
            allowed_doc="1-64 letters, digits, `.`, `_`, `-` (it becomes part of the run id)",
        )
    )
    description: str = field(default="", metadata=text_field())
    # Of k, for the run's estimate (docs/model.md §4.2).
    estimator: EstimatorName = field(
        default=DEFAULT_ESTIMATOR,
        metadata=choice(
            ESTIMATOR_NAMES,
            doc="how the run estimates k ([model.md §4.2](model.md#42-estimators-and-scatter-models)); "
            "the paper's fit is always computed beside it",
        ),
    )
    detector: DetectorParams = field(
        default=DetectorParams(),
        metadata=section(
            default_doc="the detector's defaults",
            doc="the fields of [model.md §7](model.md#7-slip-detection)",
            expand_doc=False,
        ),
    )
    ramp: RampSettings = field(default=RampSettings(), metadata=section())
    force_ceiling_n: float | None = field(
        default=None,
        metadata=number(0.1, 500.0, unit="N", within="limits", default_doc="none (the rig's applies)"),
    )
    step_timeout_margin_s: float = field(default=5.0, metadata=number(0.1, 600.0, unit="s", within="limits"))
    control_period_s: float = field(
        default=0.02,
        metadata=number(0.001, 0.1, unit="s", doc="every load-cell sample is processed whatever the period"),
    )
    trials: tuple[TrialPlan, ...] = field(  # the fixed blocks' trials
        metadata=custom(
            key="blocks", allowed_doc=f"a list of 1-{MAX_BLOCKS} blocks, at most {MAX_TRIALS} trials in all"
        )
    )
    adaptive: tuple[AdaptiveBlock, ...] = ()
    estimates_from: str | None = None  # "run" (earlier block of this protocol) or a file path
    detector_given: frozenset[str] = frozenset()  # the detector fields the file set (the rest: defaults)

    @property
    def kinds(self) -> set[str]:
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
            "detector": ",".join(f"{k}={v!r}" for k, v in self.detector.to_mapping().items()),
            "control_period_s": repr(self.control_period_s),
            "estimator": self.estimator,
        }


def load_protocol(
    path: str | Path, *, seed: int = 0, joint_count: int | None = None, joints_from: str = ""
) -> Protocol:
    """Load, validate and expand a protocol file; `seed` drives shuffling.

    `joint_count`: the link's joints, which every configuration must list; `joints_from` names where
    that count comes from (the rig config's article), for the error when one does not.
    """
    p = Path(path)
    text = read_text_file(p, what="a protocol YAML file")
    return parse_protocol(
        parse_yaml(text, str(p)),
        source=str(p),
        text=text,
        seed=seed,
        joint_count=joint_count,
        joints_from=joints_from,
        base_dir=p.parent,
    )


def parse_protocol(
    data: Any,
    *,
    source: str,
    text: str = "",
    seed: int = 0,
    joint_count: int | None = None,
    joints_from: str = "",
    base_dir: Path | None = None,
) -> Protocol:
    """Validate a parsed protocol mapping and expand its blocks into trials."""
    top = Section(data, source)
    reject_undeclared(top, Protocol)
    estimator = check_estimator(read_field(top, Protocol, "estimator"))
    fmt = top.string("format")
    if fmt != PROTOCOL_FORMAT:
        raise top.error("format", f"'{fmt}' is not supported; allowed: {PROTOCOL_FORMAT}")
    detector = _detector(top.section("detector", default={}))
    ramp = _ramp(top.section("ramp", default={}))
    limits = top.section("limits", default={})
    limits.reject_unknown(keys_within(Protocol, "limits"))
    ceiling = read_field(limits, Protocol, "force_ceiling_n")
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
            chosen = _adaptive_block(block, b, used, ramp, joint_count, estimator, joints_from)
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
                new = _joint_estimation_block(block, b, used, rng, joint_count, joints_from)
            case TrialKind.LINK_VALIDATION:
                new = _link_validation_block(block, b, used, joint_count, joints_from)
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
            source_of_estimates = read_field(block, LinkValidationBlockFields, "estimates_from")
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
    given = {
        "source": Path(source),
        "text": text,
        "format": fmt,
        "name": name,
        "estimator": estimator,
        "detector": detector,
        "detector_given": frozenset(str(key) for key in top.section("detector", default={}).data),
        "ramp": ramp,
        "trials": tuple(trials),
        "adaptive": tuple(adaptive),
        "estimates_from": estimates_from,
    }
    return Protocol(**read_fields(top, Protocol, given=given))


def _detector(sec: Section) -> DetectorParams:
    """Detector settings, validated by the model's own parameter type."""
    for key, value in sec.data.items():
        if isinstance(value, int) and abs(value) > 1e300:  # beyond the float range
            digits = int(value.bit_length() * math.log10(2)) + 1
            raise sec.error(
                str(key), f"an integer of {digits} digits is out of range; allowed: docs/model.md §7"
            )
    try:
        return DetectorParams.from_mapping(dict(sec.data), source=f"{sec.source}: detector")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def _ramp(sec: Section) -> RampSettings:
    reject_undeclared(sec, RampSettings)
    fast = read_field(sec, RampSettings, "fast_speed_rad_s")
    slow = read_field(sec, RampSettings, "slow_speed_rad_s")
    if slow > fast:
        raise sec.error("slow_speed_rad_s", f"{slow} must not exceed fast_speed_rad_s ({fast})")
    values = read_fields(sec, RampSettings, given={"fast_speed_rad_s": fast, "slow_speed_rad_s": slow})
    return RampSettings(**values)


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
        where = f"steps[{i}]"
        if name not in tuple(StepKind):
            raise block.error(where, f"unknown step '{name}'; allowed: {', '.join(StepKind)}")
        step = StepKind(name)
        if step in LINK_ONLY_STEPS and kind != TrialKind.LINK_VALIDATION:
            raise block.error(where, f"step '{name}' needs kind: link_validation")
        opts = Section(options, block.source, block.field(where))
        reject_undeclared(opts, STEP_OPTIONS.get(step, NoOptions))
        steps.append(_step(step, opts, kind))
    names = [s.kind for s in steps]
    if names.count(StepKind.RAMP_UNTIL_SLIP) != 1:
        raise block.error("steps", "exactly one 'ramp_until_slip' step is required per trial")
    after_ramp = names[names.index(StepKind.RAMP_UNTIL_SLIP) + 1 : names.index(StepKind.RAMP_UNTIL_SLIP) + 2]
    if after_ramp != [StepKind.UNLOAD]:
        raise block.error(
            "steps",
            "an 'unload' step must come right after 'ramp_until_slip' (the line is released before "
            "anything else: nothing waits beside a loaded line)",
        )
    return tuple(steps)


def _step(step: StepKind, opts: Section, kind: TrialKind) -> StepSpec:
    """One step of a template with its options (each kind reads its own; the others have none)."""
    match step:
        case StepKind.PROMPT:
            return StepSpec(step, text=_prompt_text(opts, DEFAULT_PROMPTS[kind]))
        case StepKind.PAUSE:
            return StepSpec(step, duration_s=read_field(opts, PauseOptions, "duration_s"))
        case StepKind.TARE:
            return StepSpec(step, duration_s=read_field(opts, TareOptions, "settle_s"))
        case StepKind.BEND | StepKind.MEASURE | StepKind.RAMP_UNTIL_SLIP | StepKind.UNLOAD | StepKind.RESET:
            return StepSpec(step)
        case _:
            assert_never(step)


def _joint(block: Section, joint_count: int | None, joints_from: str) -> int:
    """A block's `joint`: 1..J, J the rig config's link when it is known (`joints_from` names it)."""
    raw = block.raw("joint", default=1)
    if joints_from and joint_count is not None and isinstance(raw, int) and raw > joint_count:
        raise block.error(
            "joint", f"{raw}; allowed: 1..{joint_count}, the joints of the link in {joints_from}"
        )
    return block.integer("joint", default=1, min_value=1, max_value=joint_count or MAX_JOINTS)


def _joint_estimation_block(
    block: Section, b: int, offset: int, rng: random.Random, joint_count: int | None, joints_from: str = ""
) -> list[TrialPlan]:
    for key in ADAPTIVE_KEYS:
        if block.has(key):
            where = "set it at the protocol's top level, or " if key == "estimator" else ""
            raise block.error(
                key, f"{where}only with design: adaptive; allowed here: distances_m, repeats, shuffle"
            )
    reject_undeclared(block, FixedBlockFields)
    joint = _joint(block, joint_count, joints_from)
    distances = read_field(block, FixedBlockFields, "distances_m")
    repeats = read_field(block, FixedBlockFields, "repeats")
    steps = _steps(block, TrialKind.JOINT_ESTIMATION)
    order = [(d, r) for r in range(1, repeats + 1) for d in distances]
    if read_field(block, FixedBlockFields, "shuffle"):
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
    joints_from: str = "",
) -> AdaptiveBlock:
    """A `design: adaptive` joint-estimation block (docs/formats.md §1), validated."""
    for key in FIXED_KEYS:
        if block.has(key):
            raise block.error(
                key,
                "not with design: adaptive (the planner chooses the distances); allowed: distance_range_m",
            )
    reject_undeclared(block, AdaptiveBlockFields)
    joint = _joint(block, joint_count, joints_from)
    lo, hi = read_field(block, AdaptiveBlockFields, "distance_range_m")
    if not lo < hi:
        raise block.error(
            "distance_range_m", f"[{lo}, {hi}]; allowed: [shortest, longest] with shortest < longest"
        )
    max_trials = read_field(block, AdaptiveBlockFields, "max_trials")
    min_trials = block.integer("min_trials", default=min(10, max_trials), min_value=2, max_value=max_trials)
    startup = block.integer(
        "startup_trials", default=min(DEFAULT_STARTUP_TRIALS, max_trials), min_value=2, max_value=max_trials
    )
    estimator = read_field(block, AdaptiveBlockFields, "estimator", default=protocol_estimator)

    def declared(name: str) -> Any:
        return read_field(block, AdaptiveBlockFields, name)

    design = DesignSettings(
        distance_min_m=lo,
        distance_max_m=hi,
        distance_count=declared("distance_count"),
        target_half_width_rel=declared("target_half_width_rel"),
        max_trials=max_trials,
        min_trials=min_trials,
        startup_trials=startup,
        min_spread_fraction=declared("min_spread_fraction"),
        estimator=check_estimator(estimator),
        stop_scale_confidence=declared("stop_scale_confidence"),
    )
    fraction = declared("max_force_fraction")
    return AdaptiveBlock(
        block=b,
        first_trial_id=offset + 1,
        joint=joint,
        steps=_steps(block, TrialKind.JOINT_ESTIMATION),
        design=design,
        max_force_fraction=fraction,
    )


def _link_validation_block(
    block: Section, b: int, offset: int, joint_count: int | None, joints_from: str
) -> list[TrialPlan]:
    reject_undeclared(block, LinkValidationBlockFields)
    repeats = read_field(block, LinkValidationBlockFields, "repeats")
    tolerance_rad = math.radians(read_field(block, LinkValidationBlockFields, "bend_tolerance_deg"))
    corrections = read_field(block, LinkValidationBlockFields, "bend_corrections")
    steps = _steps(block, TrialKind.LINK_VALIDATION)
    configs = block.sequence("configurations_deg", min_length=1, max_length=MAX_ITEMS)
    angles: list[tuple[float, ...]] = []
    for c, raw in enumerate(configs):
        entry = Section({"angles": raw}, block.source, f"{block.field('configurations_deg')}[{c}]")
        if joints_from and joint_count is not None and isinstance(raw, list) and len(raw) != joint_count:
            raise entry.error(
                "angles",
                f"expected {joint_count} numbers, one per joint of the link in {joints_from}, got "
                f"{len(raw)}: this protocol is for another link; use a rig config whose article is that link",
            )
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
                    bend_tolerance_rad=tolerance_rad,
                    bend_corrections=corrections,
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
    for name, spec, conversion in fields:
        if name not in PROMPT_FIELDS or conversion is not None or not _PROMPT_SPEC.fullmatch(spec or ""):
            shown = "{" + name + (f"!{conversion}" if conversion else "") + (f":{spec}" if spec else "") + "}"
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


def for_loadcell_rate(protocol: Protocol, rate_hz: float) -> Protocol:
    """The protocol with the detector's rate-dependent defaults for a cell at `rate_hz` samples/s.

    Fields the protocol's `detector:` section set are kept (`model.slip_detector.params_for_rate`).
    """
    detector = params_for_rate(protocol.detector, protocol.detector_given, rate_hz)
    return protocol if detector == protocol.detector else replace(protocol, detector=detector)
