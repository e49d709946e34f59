"""The object-level simulated devices give the byte-level rig's trial results for the same seed."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from rig.errors import ConfigError
from rig.hw.dxl.control_table import CURRENT_UNIT_A, RAD_S_PER_VELOCITY_UNIT
from rig.hw.seams import OperatingMode
from rig.inputs.rig_config import load_rig_config
from rig.records import TrialOutcome
from rig.rigs import open_rig
from rig.runner.execute import RunReport, RunRequest, execute_run, prepare_run
from rig.runner.progress import SilentProgress
from rig.sim.kinds import DeviceLevel
from rig.sim.loadcell.emulator import SignalModel
from rig.sim.loadcell.inprocess_line import simulated_load_cell
from rig.sim.object_devices import ObjectLoadCell
from rig.sim.physics.link_presets import make_preset
from rig.sim.simulated_rig import simulated_rig
from rig.sim.virtual_clock import VirtualClock

REPO = Path(__file__).resolve().parents[1]
JOINT_ESTIMATION = REPO / "protocols" / "joint_estimation.yaml"
G = 9.80665


def _run(devices: str, seed: int, out: Path) -> RunReport:
    prepared = prepare_run(RunRequest(JOINT_ESTIMATION, None, out / devices, seed, run_id="r"))
    return execute_run(prepared, open_rig(prepared, devices=devices), SilentProgress())


@pytest.mark.slow
def test_same_seed_same_trials_at_both_device_levels(tmp_path: Path) -> None:
    """Same trial count, outcomes, distances; slip loads apart by load-cell noise only; same k to 0.1 %.

    The world's draws (capacities, scatter) are the same at both levels. What differs is time: a
    byte-level bus transaction takes virtual time, an object-level call none, so the winch's ramp
    and the 1 kHz samples fall a fraction of a millisecond apart and the detector's peak is another
    noisy sample near the same tension. The difference of two such peaks is bounded by a few load
    cell noise sds (5 mN RMS), far below a slip load's trial-to-trial scatter (8.5 %, ~1 N).
    """
    seed = 3
    byte = _run("byte", seed, tmp_path)
    obj = _run("object", seed, tmp_path)
    assert not byte.aborted and not obj.aborted
    assert byte.completed == obj.completed == byte.planned == 24
    assert [t.trial_id for t in byte.trials] == [t.trial_id for t in obj.trials]
    assert [t.distance_m for t in byte.trials] == [t.distance_m for t in obj.trials]
    assert [t.outcome for t in byte.trials] == [t.outcome for t in obj.trials]
    assert all(t.outcome == TrialOutcome.SLIP for t in byte.trials)
    preset = make_preset("link1", seed)
    noise_kg = preset.loadcell_noise_n / G
    diffs = [b.slip_mass_kg - o.slip_mass_kg for b, o in zip(byte.trials, obj.trials, strict=True)]  # type: ignore[operator]
    assert max(abs(d) for d in diffs) <= 4 * math.sqrt(2) * noise_kg
    rms = math.sqrt(sum(d * d for d in diffs) / len(diffs))
    assert rms <= 1.5 * math.sqrt(2) * noise_kg
    assert byte.truth is not None and obj.truth is not None
    assert byte.truth.k_kg_m == obj.truth.k_kg_m
    assert byte.estimate is not None and obj.estimate is not None
    assert obj.estimate.k == pytest.approx(byte.estimate.k, rel=1e-3)


def test_object_load_cell_reads_the_emulators_counts() -> None:
    """Same signal model, same seed, same sample times: the same ADC counts and forces as the real driver."""

    def tension(t_ns: int) -> float:
        return 5.0 + 3.0 * math.sin(t_ns / 7e7)

    signal = SignalModel(noise_counts=400.0)
    clock_a = VirtualClock()
    driver, _ = simulated_load_cell(tension, clock_a, rate_hz=1000.0, signal=signal, seed=11)
    clock_b = VirtualClock()
    cell = ObjectLoadCell(tension, clock_b, rate_hz=1000.0, signal=signal, seed=11)
    driver.open()
    cell.open()
    byte_samples, object_samples = [], []
    for _ in range(30):
        clock_a.sleep(0.02)
        clock_b.sleep(0.02)
        byte_samples += driver.poll()
        object_samples += cell.poll()
    driver.close()
    # The driver has a line once it crossed the wire: compare the samples both have by now.
    n = min(len(byte_samples), len(object_samples))
    assert n > 590
    assert [s.raw for s in byte_samples[:n]] == [s.raw for s in object_samples[:n]]
    assert [s.force_n for s in byte_samples[:n]] == pytest.approx([s.force_n for s in object_samples[:n]])


def test_object_rig_refuses_timed_faults() -> None:
    """Timed faults corrupt the emulators' bytes; the object-level rig has none and says so."""
    config = load_rig_config(None)
    assert config.simulation is not None
    fault = {"device": "logger", "kind": "write_error", "after_bytes": 1000}
    section = dataclasses.replace(config.simulation, data={**config.simulation.data, "faults": [fault]})
    faulty = dataclasses.replace(config, simulation=section)
    with pytest.raises(ConfigError, match="faults"):
        simulated_rig(faulty, seed=0, devices=DeviceLevel.OBJECT)


@pytest.mark.parametrize("scenario", ["additive-scatter", "mixed-scatter", "mixed", "noisy-cell"])
def test_object_rig_builds_the_same_world_as_the_byte_level_rig(scenario: str) -> None:
    """Scatter shape, slip kinds and load-cell artefacts of a scenario reach the object-level rig too."""
    config = load_rig_config(REPO / "protocols" / "rigs" / "scenarios" / f"{scenario}.yaml")
    byte = simulated_rig(config, seed=4)
    obj = simulated_rig(config, seed=4, devices=DeviceLevel.OBJECT)
    assert obj.world.preset == byte.devices.world.preset
    assert obj.world.truth() == byte.devices.world.truth()
    assert (obj.session.load_cell.artefacts is None) == (byte.devices.loadcell_emulator.artefacts is None)
    if scenario == "noisy-cell":
        assert obj.session.load_cell.artefacts is not None


def test_a_reboot_restores_the_settings_and_the_torque_at_both_device_levels() -> None:
    """A latched overload drops the torque; the reboot clears it and, as the driver does, puts back
    what the host had set (goal current, profile, torque on). The object-level bus once left the
    torque off and the profile at its default, so a runner that rebooted a winch could not unwind it."""
    config = load_rig_config(None)
    byte_rig, object_rig = (
        simulated_rig(config, seed=0),
        simulated_rig(config, seed=0, devices=DeviceLevel.OBJECT),
    )
    levels = [
        (byte_rig.session.servos, byte_rig.devices.bus.set_hardware_error, byte_rig.devices.bus.servo(1)),
        (
            object_rig.session.servos,
            object_rig.devices.bus.set_hardware_error,
            object_rig.devices.bus.servo(1),
        ),
    ]
    for servos, latch, servo in levels:
        servos.connect()
        servos.set_operating_mode(1, OperatingMode.CURRENT_BASED_POSITION, goal_current_a=0.3)
        servos.set_profile(1, velocity_rad_s=1.0)
        servos.set_torque([1], True)
        latch(1, 0x20)  # overload (Hardware Error Status bit 5)
        assert servos.read_states()[1].hardware_error == 0x20 and not servo.torque_enabled
        servos.reboot(1)
        assert servos.read_states()[1].hardware_error == 0 and servo.torque_enabled
    restored = object_rig.devices.bus.servo(1)
    assert restored.goal_current_units * CURRENT_UNIT_A == pytest.approx(0.3, abs=CURRENT_UNIT_A)
    assert restored.profile_velocity_units * RAD_S_PER_VELOCITY_UNIT == pytest.approx(
        1.0, abs=RAD_S_PER_VELOCITY_UNIT
    )
