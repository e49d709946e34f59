"""One valid example payload per rig topic, built with the schema builders (for tests, docs and checks)."""

from __future__ import annotations

from typing import Any

import numpy as np

from rig.log import schemas as S

EXAMPLE_TIME_NS = 1_767_225_600_123_456_789  # 2026-01-01T00:00:00.123456789Z


def example_payloads(time_ns: int = EXAMPLE_TIME_NS) -> dict[str, dict[str, Any]]:
    """A payload for every topic in `schemas.TOPICS` (same order), with times around `time_ns`."""
    return {
        S.LOADCELL: S.loadcell_sample(raw=123456, force_n=1.25, seq=7, device_time_us=None),
        S.SERVO_STATE: S.servo_state(
            servo_id=1,
            role="winch",
            position_rad=0.5,
            velocity_rad_s=-0.1,
            current_a=0.2,
            hardware_error=0,
            moving=True,
        ),
        S.SERVO_COMMAND: S.servo_command(
            servo_id=2, role="bend", command="goal_position", value=1.0, unit="rad"
        ),
        S.TRIAL_STATE: S.trial_state(trial_id=3, phase=S.TrialPhase.RAMP_SLOW, step="ramp"),
        S.SLIP: S.slip_event(
            trial_id=3,
            onset_time_ns=time_ns,
            detection_time_ns=time_ns + 5_000_000,
            peak_time_ns=time_ns - 1_000_000,
            peak_force_n=12.5,
            force_after_n=8.0,
            drop_fraction=0.36,
            detector={"drop_fraction": 0.2, "window_s": 0.05},
            trigger="drop",
            joint=None,
        ),
        S.TRIAL_RESULT: S.trial_result(
            trial_id=3,
            kind="link_validation",
            start_time_ns=time_ns,
            end_time_ns=time_ns + 9_000_000_000,
            outcome="slip",
            peak_force_n=12.5,
            slip_mass_kg=1.2755,
            predicted_mass_kg=1.3,
            configuration={"joint_angles_rad": [0.0, 0.5], "transforms": np.eye(4)[None].repeat(2, 0)},
            slipped_joint=2,
            repeat=1,
            lever_arms_m=[0.1, 0.07],
        ),
        S.ESTIMATE: S.estimate(
            trial_id=3,
            fit={
                "n": 4,
                "k": 0.167,
                "k_ci": (0.148, 0.185),
                "r2": float("nan"),
                "dfe": 3,
                "constant": "paper",
            },
            joints=[{"joint": 1, "capacity_nm": 1.6, "ci_lo_nm": 1.4, "ci_hi_nm": 1.8}],
        ),
        S.LOG: S.log_message(time_ns=time_ns, level=S.LogLevel.WARNING, message="tension high", line=12),
    }
