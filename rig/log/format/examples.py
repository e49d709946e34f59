"""One valid example payload per rig topic, made by the records themselves (for tests, docs and checks)."""

from __future__ import annotations

from typing import Any

from model.fit import FitSummary
from model.slip_detector import SlipEvent
from rig.hw.dxl.transport import BusStats
from rig.hw.seams import LoadCellLineStats
from rig.log.format import schemas as S
from rig.log.format.link_scene import LinkGeometry, LinkScene
from rig.records import (
    ConfigurationMeasurement,
    Estimate,
    JointCapacity,
    LogLevel,
    LogMessage,
    ServoCommand,
    ServoCommandName,
    SlipMessage,
    TrialKind,
    TrialOutcome,
    TrialPhase,
    TrialResult,
    TrialState,
    TrialWireStats,
)
from rig.vocabulary import ConfigurationSourceKind, MeasurementStage, ServoRole

EXAMPLE_TIME_NS = 1_767_225_600_123_456_789  # 2026-01-01T00:00:00.123456789Z


def example_payloads(time_ns: int = EXAMPLE_TIME_NS) -> dict[str, dict[str, Any]]:
    """A payload for every topic in `schemas.TOPICS` (same order), with times around `time_ns`."""
    event = SlipEvent(
        onset_time_ns=time_ns,
        detection_time_ns=time_ns + 5_000_000,
        peak_time_ns=time_ns - 1_000_000,
        peak_force_n=12.5,
        force_after_n=8.0,
        drop_fraction=0.36,
        trigger="drop",
    )
    scene = LinkScene(
        LinkGeometry((0.03, 0.03, 0.03), 0.01, (0.0, 0.0, 0.03), (0.0, -1.0, 0.0)),
        time_ns,
        trial_id=3,
        joint_angles_rad=(0.1, -0.2, 0.05),
        tension_n=12.5,
        slipped_joint=2,
        slipped=True,
    )
    fit = FitSummary(
        n=4,
        k=0.167,
        k_ci=(0.148, 0.185),
        sse=0.001,
        sst=0.2,
        r2=float("nan"),
        rmse=0.018,
        dfe=3,
        se=0.003,
        level=0.99,
        constant="paper",
        c=6.9,
        radius_m=0.01,
        mu_delta0_pa=2.4e5,
        mu_delta0_ci_pa=(2.1e5, 2.6e5),
        capacity_nm=1.64,
        capacity_ci_nm=(1.45, 1.81),
    )
    return {
        S.LOADCELL: S.loadcell_sample(raw=123456, force_n=1.25, seq=7, device_time_us=None),
        S.SERVO_STATE: S.servo_state(
            servo_id=1,
            role=ServoRole.WINCH,
            position_rad=0.5,
            velocity_rad_s=-0.1,
            current_a=0.2,
            hardware_error=0,
            moving=True,
        ),
        S.SERVO_COMMAND: ServoCommand(
            2, ServoRole.BENDER, ServoCommandName.GOAL_POSITION, 1.0, "rad"
        ).to_payload(),
        S.TRIAL_STATE: TrialState(3, TrialPhase.RAMP_SLOW, "ramp").to_payload(),
        S.SLIP: SlipMessage(3, event, {"drop_fraction": 0.2, "slope_n_per_s": None}, None).to_payload(),
        S.TRIAL_RESULT: TrialResult(
            trial_id=3,
            kind=TrialKind.LINK_VALIDATION,
            repeat=1,
            joint=None,
            distance_m=None,
            configuration_index=2,
            joint_angles_rad=(0.0, 0.5),
            start_time_ns=time_ns,
            end_time_ns=time_ns + 9_000_000_000,
            outcome=TrialOutcome.SLIP,
            peak_force_n=12.5,
            slip_mass_kg=1.2755,
            predicted_force_n=12.74,
            predicted_mass_kg=1.3,
            percentage_error=1.92,
            slipped_joint=2,
            lever_arms_m=(0.1, 0.07),
            tare_n=0.01,
        ).to_payload(),
        S.ESTIMATE: Estimate(3, fit, (JointCapacity(1, 1.6, 1.4, 1.8),)).to_payload(),
        S.TRIAL_LINKS: TrialWireStats(
            3,
            BusStats(operations=220, attempts=223, retries=3, timeouts=1, corrupt=2, recovered=3),
            LoadCellLineStats(4100, 1, 0, 3, 2, 0),
        ).to_payload(),
        S.LOG: LogMessage(time_ns, LogLevel.WARNING, "tension high", line=12).to_payload(),
        S.LINK_FRAMES: scene.frames_payload(),
        S.LINK_SCENE: scene.scene_payload(),
        S.CONFIGURATION_MEASURED: ConfigurationMeasurement(
            trial_id=3,
            source=ConfigurationSourceKind.CAMERA,
            stage=MeasurementStage.BENT,
            measured_time_ns=time_ns,
            attempt=1,
            configuration_index=2,
            joint_angles_rad=(0.01, -0.49),
            uncertainty_rad=(0.007, 0.007),
            commanded_angles_rad=(0.0, -0.5),
        ).to_payload(),
    }
