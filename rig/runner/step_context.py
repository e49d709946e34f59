"""What every step of a trial works with: the rig, the protocol, the control loop and the recorder."""

from __future__ import annotations

from dataclasses import dataclass

from model.slip_detector import DetectorParams
from rig.hw.session import RigSession
from rig.inputs.protocol import Protocol
from rig.inputs.rig_config import DEFAULT_LOADCELL_RATE_HZ, RigConfig
from rig.runner.control_loop import ControlLoop
from rig.runner.link_view import LinkView
from rig.runner.recorder import RunRecorder
from rig.runner.run_estimates import RunEstimator
from rig.safety.release import LineRelease

BENDER_SPEED_RAD_S = 2.0


@dataclass
class StepContext:
    """The run's parts a step uses; `winch_zero_rad` is set on connecting (and moved by a winch reboot)."""

    protocol: Protocol
    config: RigConfig
    session: RigSession
    loop: ControlLoop
    recorder: RunRecorder
    estimator: RunEstimator
    detector_params: DetectorParams
    line_stiffness_n_per_m: float
    link_view: LinkView
    winch_zero_rad: float | None = None
    loadcell_rate_hz: float = DEFAULT_LOADCELL_RATE_HZ  # nominal (`rig_config.nominal_loadcell_rate_hz`)
    rate_mismatch_noted: bool = False  # the run has warned once that the measured rate differs
    reel_direction_verified: bool = False  # a ramp of this invocation saw the tension rise as it reeled in

    def line_release(self) -> LineRelease:
        """A release starting from a copy of what the loop saw last (`rig.safety.release`)."""
        return LineRelease(
            self.session,
            self.recorder,
            self.protocol.ramp,
            control_period_s=self.protocol.control_period_s,
            tare_n=self.loop.tare_n,
            last=self.loop.reading(),
            patience_s=self.config.servos.release_patience_s,
            margin_s=self.config.servos.release_margin_s,
            settle_s=self.config.loadcell.slack_settle_s,
            port=self.config.servos.port,
        )
