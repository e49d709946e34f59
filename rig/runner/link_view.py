"""The runner's side of the 3D view: when to log the link's frames and scene (`rig.log.format.link_scene`).

Logged when the ramp starts (the configuration is known then: measured, else commanded), once a
second of the ramp with the tension, at a slip (the slipped joint red) and when the trial ends.
The topics go into the MCAP file and to the live server like every other, so a log opened in
Foxglove or Lichtblick shows the link without a server. Nothing is built for a run that keeps no
log rows (`rig study`).
"""

from __future__ import annotations

from rig.inputs.protocol import TrialPlan
from rig.inputs.rig_config import ArticleConfig
from rig.log.format import schemas
from rig.log.format.link_scene import LinkGeometry, LinkScene
from rig.runner.recorder import RunRecorder
from rig.runner.results import TrialMeasurements
from rig.vocabulary import TrialKind

UPDATE_PERIOD_S = 1.0  # scene updates during a ramp, in the run's time


def geometry_of(article: ArticleConfig) -> LinkGeometry:
    """The view's geometry from the rig config's article."""
    return LinkGeometry(
        segment_lengths_m=article.segment_lengths_m,
        joint_radius_m=article.joint_radius_m,
        point_m=article.point_m,
        direction=article.direction,
    )


class LinkView:
    """Logs `/rig/link/frames` and `/rig/link/scene` for the trial under way."""

    def __init__(self, recorder: RunRecorder, article: ArticleConfig) -> None:
        self.recorder = recorder
        self.geometry = geometry_of(article)
        self._next_update_ns = 0

    @property
    def enabled(self) -> bool:
        return self.recorder.wants_ticks

    def _scene(self, trial: TrialPlan, found: TrialMeasurements, tension_n: float, time_ns: int) -> LinkScene:
        angles = found.joint_angles_rad or (0.0,) * self.geometry.joint_count
        estimating = trial.kind is TrialKind.JOINT_ESTIMATION
        return LinkScene(
            self.geometry,
            time_ns,
            trial_id=trial.trial_id,
            joint_angles_rad=tuple(angles),
            tension_n=tension_n,
            tested_joint=trial.joint if estimating else None,
            distance_m=trial.distance_m if estimating else None,
            slipped_joint=found.slipped_joint if found.slipped_joint is not None else trial.joint,
            slipped=found.event is not None,
        )

    def ramp_started(
        self, trial: TrialPlan, found: TrialMeasurements, tension_n: float, time_ns: int
    ) -> None:
        """The configuration the trial loads: frames and scene."""
        if not self.enabled:
            return
        scene = self._scene(trial, found, tension_n, time_ns)
        self.recorder.write(schemas.LINK_FRAMES, scene.frames_payload(), time_ns)
        self.recorder.write(schemas.LINK_SCENE, scene.scene_payload(), time_ns)
        self._next_update_ns = time_ns + round(UPDATE_PERIOD_S * 1e9)

    def ramp_tick(self, trial: TrialPlan, found: TrialMeasurements, tension_n: float, time_ns: int) -> None:
        """The scene with the tension now, at most once per `UPDATE_PERIOD_S`."""
        if time_ns < self._next_update_ns or not self.enabled:
            return
        self._next_update_ns = time_ns + round(UPDATE_PERIOD_S * 1e9)
        self.recorder.write(
            schemas.LINK_SCENE, self._scene(trial, found, tension_n, time_ns).scene_payload(), time_ns
        )

    def show(self, trial: TrialPlan, found: TrialMeasurements, tension_n: float, time_ns: int) -> None:
        """The scene now, unthrottled: at a slip (the slipped joint marked) and at the trial's end."""
        if not self.enabled:
            return
        self.recorder.write(
            schemas.LINK_SCENE, self._scene(trial, found, tension_n, time_ns).scene_payload(), time_ns
        )
