"""The simulated world's slip kinds and scatter shapes: each kind's tension trace, the truth, the moments."""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import replace

import numpy as np
import pytest

from rig.sim.kinds import SlipKind
from rig.sim.physics.configuration_source import SimConfigurationSource
from rig.sim.physics.link_presets import make_preset
from rig.sim.physics.world import SimWorld
from rig.sim.settings import CapacityScatter, SlipKindMix
from rig.vocabulary import TrialKind
from tests.helpers import ScriptedShaft, set_up_trial

MS = 1_000_000
S = 1_000_000_000
RATE_RAD_S = 0.08  # the protocol's slow ramp: 4 N/s on the default line and drum
DISTANCE_M = 0.15


def only(kind: str, **params: object) -> SlipKindMix:
    """A mix of one kind."""
    probabilities = tuple(1.0 if k == kind else 0.0 for k in tuple(SlipKind))
    return SlipKindMix(probabilities=probabilities, **params)  # type: ignore[arg-type]


def world_of(mix: SlipKindMix, seed: int = 3, offset_ns: int = 0) -> tuple[SimWorld, ScriptedShaft]:
    preset = make_preset("link1", seed=seed, slip_mix=mix)
    shaft = ScriptedShaft()
    return SimWorld(preset, shaft, seed=seed, run_clock_offset_ns=offset_ns), shaft


def ramp(world: SimWorld, shaft: ScriptedShaft, seconds: float, rate_rad_s: float = RATE_RAD_S) -> np.ndarray:
    """Reel in at `rate_rad_s` for `seconds` in 1 ms steps; the tension after each step."""
    out = []
    for _ in range(round(seconds * 1000)):
        shaft.present_position_rad += rate_rad_s * 1e-3
        world.advance_to(world.now_ns + MS)
        out.append(world.tension_n)
    return np.array(out)


def load_to_just_below(world: SimWorld, shaft: ScriptedShaft, tension_n: float) -> None:
    """Put the winch where the line pulls `tension_n` (no slip yet)."""
    shaft.present_position_rad = world.line.winch_angle_for_tension_rad(tension_n, world.article.take_up_m)
    world.advance_to(world.now_ns + MS)


def test_sudden_and_small_drop_fall_by_their_fraction_within_a_few_ms() -> None:
    for mix, low, high in ((only("sudden"), 0.19, 0.21), (only("small_drop"), 0.03, 0.15)):
        world, shaft = world_of(mix)
        trial = set_up_trial(world, TrialKind.JOINT_ESTIMATION, DISTANCE_M)
        load_to_just_below(world, shaft, trial.slip_force_n - 0.05)
        trace = ramp(world, shaft, 0.1)
        (slip,) = world.slips
        assert slip.onset.kind == mix_kind(mix)
        assert slip.end_ns is not None and slip.end_ns - slip.onset.onset_ns <= 5 * MS
        drop = 1 - slip.tension_after_n / slip.onset.peak_tension_n  # type: ignore[operator]
        assert low - 0.005 <= drop <= high + 0.005
        if slip.onset.kind == "small_drop":
            assert drop == pytest.approx(trial.slip.drop_fraction, abs=0.005)
        assert trace.max() == pytest.approx(slip.onset.peak_tension_n, abs=0.01)


def mix_kind(mix: SlipKindMix) -> str:
    return tuple(SlipKind)[int(np.argmax(mix.probabilities))]


def test_creep_sags_slowly_over_its_duration_while_the_winch_reels() -> None:
    world, shaft = world_of(only("creep", creep_duration_s=(0.5, 0.5), creep_drop_fraction=(0.05, 0.05)))
    trial = set_up_trial(world, TrialKind.JOINT_ESTIMATION, DISTANCE_M)
    load_to_just_below(world, shaft, trial.slip_force_n - 0.02)
    trace = ramp(world, shaft, 1.0)
    creep = world.slips[0]
    assert creep.onset.kind == "creep"
    assert creep.end_ns is not None and (creep.end_ns - creep.onset.onset_ns) == pytest.approx(
        0.5 * S, abs=2 * MS
    )
    onset = int(np.argmax(trace))
    sag = trace[onset : onset + 500]
    # A straight line from the peak down by 5 % over 0.5 s: never a jump, every step small.
    expected = creep.onset.peak_tension_n * (1 - 0.05 * np.arange(1, 501) / 500)
    assert np.abs(sag - expected).max() < 0.01
    assert np.abs(np.diff(sag)).max() < 0.01
    assert creep.tension_after_n == pytest.approx(0.95 * creep.onset.peak_tension_n, abs=0.01)
    # Then it sticks again: the winch re-tensions the line.
    assert trace[-1] > trace[onset + 500]


def test_stick_slip_is_a_train_of_drops_with_dwells() -> None:
    mix = only("stick_slip", stick_slip_drops=(4, 4), stick_slip_dwell_s=(0.03, 0.03))
    world, shaft = world_of(mix)
    trial = set_up_trial(world, TrialKind.JOINT_ESTIMATION, DISTANCE_M)
    load_to_just_below(world, shaft, trial.slip_force_n - 0.02)
    while not world.slips:  # reel until the first drop, then hold, as the runner does after a slip
        ramp(world, shaft, 0.001)
    shaft_at = shaft.present_position_rad
    world.advance_to(world.now_ns + 300 * MS)
    assert shaft.present_position_rad == shaft_at
    drops = [s for s in world.slips if s.onset.trial_index == trial.index]
    assert [s.onset.kind for s in drops] == ["stick_slip"] * 4
    fraction = trial.slip.drop_fraction
    assert fraction is not None
    for before, after in itertools.pairwise(drops):
        assert before.end_ns is not None
        assert after.onset.onset_ns - before.end_ns == pytest.approx(30 * MS, abs=MS)
        assert after.onset.peak_tension_n == pytest.approx(before.tension_after_n, abs=1e-9)
    for drop in drops:
        assert drop.tension_after_n == pytest.approx(drop.onset.peak_tension_n * (1 - fraction), abs=1e-3)
    truth = world.truth().to_json()["trials"][-1]
    assert [e["kind"] for e in truth["slip_events"]] == ["stick_slip"] * 4


def test_other_joint_slips_first_and_the_configuration_source_names_it() -> None:
    world, shaft = world_of(only("other_joint"), offset_ns=5 * S)
    source = SimConfigurationSource(world)
    trial = set_up_trial(world, TrialKind.JOINT_ESTIMATION, DISTANCE_M, joint=3)
    assert trial.slip.other_joint == 4
    other_load = trial.slip.other_load_n
    assert other_load is not None and 0.5 * trial.slip_force_n <= other_load <= 0.9 * trial.slip_force_n
    shaft.present_position_rad = world.line.winch_angle_for_tension_rad(other_load - 0.02, 0.0)
    world.advance_to(world.now_ns + MS)
    ramp(world, shaft, 0.02)
    (slip,) = world.slips
    assert slip.onset.kind == "other_joint" and slip.onset.moved_joint == 4
    assert slip.onset.onset_time_ns == slip.onset.onset_ns + 5 * S
    assert world.article.planar_joint_angles() == (0.0,)  # the specimen did not move
    drop = 1 - slip.tension_after_n / slip.onset.peak_tension_n  # type: ignore[operator]
    assert drop == pytest.approx(trial.slip.drop_fraction, abs=1e-6)
    assert source.measure().slipped_joint == 4  # != the trial's joint 3: another joint moved
    # Reeling on, the specimen itself slips at its own load, named as the trial's joint.
    ramp(world, shaft, 4.0, rate_rad_s=0.5)
    specimen = world.slips[1]
    assert specimen.onset.kind == "sudden" and specimen.onset.moved_joint == 3
    assert specimen.onset.peak_tension_n == pytest.approx(trial.slip_force_n, abs=0.03)
    assert source.measure().slipped_joint == 3


def test_no_slip_holds_beyond_the_ramps_force_limit() -> None:
    world, shaft = world_of(only("no_slip"))
    for _ in range(20):
        trial = set_up_trial(world, TrialKind.JOINT_ESTIMATION, 0.1)
        assert trial.slip.kind == "no_slip"
        assert trial.slip_force_n > 40.0 * 2  # capacities x10: far above the protocol's 40 N
    set_up_trial(world, TrialKind.JOINT_ESTIMATION, DISTANCE_M)
    ramp(world, shaft, 2.0, rate_rad_s=1.0)
    assert world.tension_n > 40.0 and not world.slips


def test_the_mix_draws_each_kind_with_its_probability_from_its_own_stream() -> None:
    probabilities = (0.3, 0.15, 0.15, 0.15, 0.15, 0.1)
    world, _ = world_of(SlipKindMix(probabilities=probabilities), seed=7)
    plain, _ = world_of(SlipKindMix(), seed=7)
    kinds = []
    for i in range(1500):
        kinds.append(set_up_trial(world, TrialKind.JOINT_ESTIMATION, 0.1 + 0.01 * (i % 10)).slip.kind)
        set_up_trial(plain, TrialKind.JOINT_ESTIMATION, 0.1 + 0.01 * (i % 10))
    counts = np.array([kinds.count(k) for k in tuple(SlipKind)]) / len(kinds)
    assert np.allclose(counts, probabilities, atol=0.03)
    # The capacity stream is untouched by the mix: the same draws as a world of sudden slips.
    for mixed, sudden in zip(world.trials, plain.trials, strict=True):
        assert mixed.capacity_factors == sudden.capacity_factors
    # Every kind of link-validation trial slips the link (other_joint is sudden there).
    assert set_up_trial(world, TrialKind.LINK_VALIDATION).slip.kind in tuple(SlipKind)


def test_truth_records_every_event_on_the_run_clock_and_is_json() -> None:
    world, shaft = world_of(SlipKindMix(probabilities=(0.2, 0.2, 0.2, 0.2, 0.2, 0.0)), offset_ns=10 * S)
    for i in range(6):
        trial = set_up_trial(world, TrialKind.JOINT_ESTIMATION, 0.12 + 0.02 * i)
        shaft.present_position_rad = 0.0
        world.advance_to(world.now_ns + MS)
        ramp(world, shaft, 1.5, rate_rad_s=1.0)
        assert trial.slip.kind in tuple(SlipKind)
    truth = json.loads(json.dumps(world.truth().to_json(), allow_nan=False))
    assert truth["scatter"]["shape"] == "multiplicative"
    events = [e for t in truth["trials"] for e in t["slip_events"]]
    assert len(events) == len(world.slips) >= 6
    for event, record in zip(events, world.slips, strict=True):
        assert event["onset_time_ns"] == record.onset.onset_ns + 10 * S
        assert event["kind"] == record.onset.kind and event["load_n"] == record.onset.peak_tension_n
    assert {t["slip_kind"] for t in truth["trials"]} <= set(tuple(SlipKind))


@pytest.mark.parametrize(
    ("scatter", "a_kg", "b"),
    [
        (CapacityScatter("multiplicative", b=0.08), 0.0, 0.08),
        (CapacityScatter("additive", a_kg=0.1), 0.1, 0.0),
        (CapacityScatter("mixed", a_kg=0.06, b=0.05), 0.06, 0.05),
    ],
)
def test_scatter_shapes_give_slip_masses_with_sd_squared_a2_plus_bm2(
    scatter: CapacityScatter, a_kg: float, b: float
) -> None:
    preset = make_preset("link1", seed=4, scatter=scatter)
    assert (preset.scatter_shape, preset.scatter_a_kg, preset.per_trial_capacity_sd) == (
        scatter.shape,
        a_kg,
        b,
    )
    world = SimWorld(preset, ScriptedShaft(), seed=4)
    for distance in (0.05, 0.25):  # slip masses near 3.2 kg and 0.65 kg
        masses = np.array(
            [set_up_trial(world, TrialKind.JOINT_ESTIMATION, distance).slip_mass_kg for _ in range(2000)]
        )
        m0 = preset.specimen_capacity_nm / (preset.g * distance)
        expected_sd = math.sqrt(a_kg**2 + (b * m0) ** 2)
        assert masses.mean() == pytest.approx(m0, abs=3 * expected_sd / math.sqrt(len(masses)) + 1e-9)
        # Clipping at ±3 sd takes 1.3 % off the sd of a normal draw.
        assert masses.std() == pytest.approx(0.987 * expected_sd, rel=0.06)
    truth = world.truth().to_json()
    assert truth["scatter"] == {"shape": scatter.shape, "a_kg": a_kg, "b": b, "sd_m": "sqrt(a^2 + (b m)^2)"}


def test_multiplicative_default_is_the_world_of_before() -> None:
    """The default preset draws exactly the factors 1 + sd·z (what every seeded result depends on)."""
    preset = make_preset("link1", seed=9)
    assert preset.slip_mix == SlipKindMix() and preset.scatter_shape == "multiplicative"
    world = SimWorld(preset, ScriptedShaft(), seed=9)
    rng = np.random.default_rng((9, 1))
    for _ in range(10):
        trial = set_up_trial(world, TrialKind.JOINT_ESTIMATION, 0.1)
        draw = float(np.clip(rng.standard_normal(1), -3, 3)[0])
        assert trial.capacity_factors == (1.0 + preset.per_trial_capacity_sd * draw,)
        assert trial.slip.kind == SlipKind.SUDDEN


def test_slip_mix_and_scatter_records_refuse_bad_values() -> None:
    with pytest.raises(ValueError, match="sum 1"):
        SlipKindMix(probabilities=(0.5, 0.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="small_drop_fraction"):
        SlipKindMix(small_drop_fraction=(0.2, 0.1))
    with pytest.raises(ValueError, match="needs a_kg"):
        CapacityScatter("additive")
    with pytest.raises(ValueError, match="additive has b = 0"):
        CapacityScatter("additive", a_kg=0.1, b=0.1)
    with pytest.raises(ValueError, match="scatter_shape"):
        replace(make_preset("link1"), scatter_shape="cubic")
