"""The simulated configuration measurement (like the paper's RGB-D camera): truth plus noise.

`SimConfigurationSource` implements `rig.hw.seams.ConfigurationSource` over a `SimWorld`. Each
`measure()` returns the configuration of the article the line is hooked to (the link, or the
single-joint specimen during joint estimation):

* a planar configuration is reported as joint angles φ_i + N(0, σ_meas) each, and transforms built
  from those noisy angles (`model.chain.planar_transforms`);
* an out-of-plane configuration (after a slip under an out-of-plane load) is reported with
  `joint_angles_rad = None` and each joint rotation perturbed by a random rotation whose rotation
  vector is N(0, σ_meas² I₃);
* on the link, `slipped_joint` is the joint whose true rotation changed between the onset of the
  first slip since the previous `measure()` and now (`model.slipped_joint.moved_joint` on the world's
  true configurations: the simulator sees the link; a slip under the winch turns a joint by a
  fraction of a degree, below a camera's noise, so the runner's own comparison of the noisy
  readings, used for a camera, would rarely tell);
* on the joint-estimation specimen, `slipped_joint` names the link joint (1-based) of the most
  recent true slip since the previous `measure()` (`SlipRecord.onset.moved_joint`), but only with probability
  `slipped_joint_report_probability` (else None, as when a camera cannot tell which joint moved),
  so a consumer's "unknown joint" path is exercised. In joint estimation a slip of the specimen
  names the trial's joint (`TrialPlan.joint`; 1 for the nominal specimen) and a slip of a
  neighbouring joint (slip kind `other_joint`) names that joint, with the slip mix's
  `other_joint_report_probability` instead: so `slipped_joint != trial.joint` (not None) means
  another joint moved.

σ_meas and the report probability come from the world's preset (so the ground truth states them).
Noise comes from the seeded streams `STREAM_MEASUREMENT` and `STREAM_SLIP_REPORT`.
"""

from __future__ import annotations

import numpy as np

from model.chain import planar_transforms
from model.slipped_joint import moved_joint
from rig.hw.seams import Clock, ConfigurationReading
from rig.sim.kinds import ArticleSetup, SlipKind
from rig.sim.physics.link import rotation_about_axis
from rig.sim.physics.link_presets import STREAM_MEASUREMENT, STREAM_SLIP_REPORT, stream_rng
from rig.sim.physics.world import SimWorld

SEEN_ROTATION_RAD = 1e-9  # the simulator sees any rotation of a joint between two measurements


class SimConfigurationSource:
    """Measures a `SimWorld`'s configuration with noise; see the module docstring."""

    def __init__(self, world: SimWorld, clock: Clock | None = None, *, seed: int | None = None) -> None:
        self._world = world
        self._clock = clock
        stream_seed = world.seed if seed is None else seed
        self._noise_rng = stream_rng(stream_seed, STREAM_MEASUREMENT)
        self._report_rng = stream_rng(stream_seed, STREAM_SLIP_REPORT)
        self.sigma_meas_rad = world.preset.sigma_meas_rad
        self.report_probability = world.preset.slipped_joint_report_probability
        self._slips_seen = len(world.slips)

    def measure(self) -> ConfigurationReading:
        """Measure the configuration with noise, and the joint that slipped since the last call if known."""
        world = self._world
        article = world.article
        sigma = self.sigma_meas_rad
        # On the joint-estimation specimen there is no link configuration to report: only which
        # joint moved (the specimen's own angle would not match the rig's article).
        angles = article.planar_joint_angles() if world.setup == ArticleSetup.LINK else None
        if angles is not None:
            noisy = np.asarray(angles) + self._noise_rng.normal(0.0, sigma, article.joint_count)
            transforms = planar_transforms(noisy, np.asarray(article.transforms[:, 2, 3]))
            noisy_angles: tuple[float, ...] | None = tuple(float(a) for a in noisy)
        else:
            transforms = article.transforms
            for i in range(article.joint_count):
                vector = self._noise_rng.normal(0.0, sigma, 3)
                angle = float(np.linalg.norm(vector))
                if angle > 0:
                    transforms[i, :3, :3] = rotation_about_axis(vector / angle, angle) @ transforms[i, :3, :3]
            noisy_angles = None

        slipped: int | None = None
        new_slips = world.slips[self._slips_seen :]
        self._slips_seen = len(world.slips)
        before = [world.link_before_slip.pop(i) for i in sorted(world.link_before_slip)]
        if world.setup == ArticleSetup.LINK:
            # The simulator sees the link's true configuration: the joint that moved since the
            # first slip began is the one whose rotation changed (model.slipped_joint).
            if new_slips and before:
                slipped = moved_joint(before[0], article.transforms, SEEN_ROTATION_RAD)
        elif new_slips:
            last = new_slips[-1]
            probability = self.report_probability
            if last.onset.kind == SlipKind.OTHER_JOINT:
                probability = world.preset.slip_mix.other_joint_report_probability
            if self._report_rng.random() < probability:
                slipped = last.onset.moved_joint
        time_ns = self._clock.time_ns() if self._clock is not None else world.now_ns
        return ConfigurationReading(
            transforms=transforms,
            time_ns=time_ns,
            joint_angles_rad=noisy_angles,
            slipped_joint=slipped,
            uncertainty_rad=(sigma,) * article.joint_count,
        )
