"""One configuration measurement during a trial: asked of the session's source and logged.

Each goes on `/rig/configuration/measured` (`rig.records.ConfigurationMeasurement`) with the
commanded angles beside it, so a log shows what was asked for and what the link took.
"""

from __future__ import annotations

from rig.errors import InputError
from rig.hw.seams import ConfigurationReading, MeasurementRequest, RequestAwareSource
from rig.inputs.protocol import TrialPlan
from rig.log.format import schemas
from rig.records import ConfigurationMeasurement
from rig.runner.step_context import StepContext
from rig.vocabulary import ConfigurationSourceKind, MeasurementStage


def measure_configuration(
    ctx: StepContext, trial: TrialPlan, *, after_slip: bool, attempt: int = 0
) -> ConfigurationReading:
    """One measurement by the session's source, logged on `/rig/configuration/measured`."""
    source = ctx.session.configuration
    assert source is not None
    if isinstance(source, RequestAwareSource):
        source.prepare(
            MeasurementRequest(trial.configuration_index, trial.joint_angles_rad, after_slip, ctx.loop.tick)
        )
    reading = source.measure()
    joints = ctx.config.article.joint_count
    if reading.joint_angles_rad is not None and len(reading.joint_angles_rad) != joints:
        raise InputError(
            f"configuration source ({ctx.session.configuration_kind}): {len(reading.joint_angles_rad)} "
            f"joint angles measured; the rig config's article has {joints} joints"
        )
    kind = ctx.session.configuration_kind or ConfigurationSourceKind.SIMULATOR
    record = ConfigurationMeasurement(
        trial_id=trial.trial_id,
        source=kind,
        stage=MeasurementStage.AFTER_SLIP if after_slip else MeasurementStage.BENT,
        measured_time_ns=reading.time_ns,
        attempt=attempt,
        configuration_index=trial.configuration_index,
        joint_angles_rad=reading.joint_angles_rad,
        uncertainty_rad=reading.uncertainty_rad,
        commanded_angles_rad=trial.joint_angles_rad,
        slipped_joint=reading.slipped_joint,
    )
    ctx.recorder.write(schemas.CONFIGURATION_MEASURED, record.to_payload(), reading.time_ns)
    return reading
