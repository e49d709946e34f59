"""The two values of g the project uses, each defined once here.

* `PAPER_G_M_S2` = 9.8 m/s²: the paper's g. The paper turns its slip masses into forces and joint
  capacities (capacity = k·g) with 9.8, so everything that reproduces or compares with the paper
  uses it: the fit (`model.fit`), slip prediction (`model.chain`), link files, rig configs
  (`article.g`), the simulated articles and `rig fit --g`'s default.
* `STANDARD_GRAVITY_M_S2` = 9.80665 m/s²: standard gravity (CGPM 1901, exact). A load-cell
  calibration with a reference mass, and an indicator that displays kg, relate mass and force with
  it, as scales and calibration certificates do; it is a default of the calibration
  (`rig calibrate --g` takes the local value) and what the emulated indicator assumes.

The two differ by 0.07 %, far below the fit's confidence bounds, but they are different facts:
changing one must not change the other.
"""

from __future__ import annotations

from typing import Final

PAPER_G_M_S2: Final[float] = 9.8
STANDARD_GRAVITY_M_S2: Final[float] = 9.80665
