"""The scatter shapes of the simulator's scenario rigs, read from their configs, for bare-statistics studies.

A study that draws synthetic slip masses m = k/l·(1 + b·e1) + a·e2 under "additive", "multiplicative"
or "mixed" scatter should draw them with the same a and b as the simulated rig of that name, so that
a bare-statistics number and an end-to-end `rig study` number are about the same world. This module
is where those a and b come from: the scenario configs in protocols/rigs/scenarios/ (and the
built-in rig for multiplicative scatter), through the simulator's own preset (`noise_scale`
included), so the configs stay the one definition.

    from studies.scatter_shapes import scenario_shapes
    scenario_shapes()["mixed"]  # ScatterShape(a_kg=0.07, b=0.06, source=...)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rig.inputs.rig_config import load_rig_config
from rig.sim.physics.link_presets import make_preset
from rig.sim.settings import require_simulated

SCENARIOS_DIR = Path(__file__).resolve().parent.parent / "protocols" / "rigs" / "scenarios"
# Shape name: the rig config whose simulated world has it (None: the built-in simulated rig).
SCENARIO_CONFIGS: dict[str, Path | None] = {
    "additive": SCENARIOS_DIR / "additive-scatter.yaml",
    "multiplicative": None,
    "mixed": SCENARIOS_DIR / "mixed-scatter.yaml",
}


@dataclass(frozen=True)
class ScatterShape:
    """sd(m)² = a² + (b·m)² of one slip mass, and the config it was read from."""

    a_kg: float
    b: float
    source: str


def rig_scatter(config_path: Path | None) -> ScatterShape:
    """The scatter of the simulated rig `config_path` (None: the built-in one), as its world draws it."""
    config = load_rig_config(config_path)
    simulation = require_simulated(config)
    preset = make_preset(simulation.preset, noise_scale=simulation.noise_scale, scatter=simulation.scatter)
    return ScatterShape(preset.scatter_a_kg, preset.per_trial_capacity_sd, config.source)


def scenario_shapes() -> dict[str, ScatterShape]:
    """Every shape of `SCENARIO_CONFIGS`, read now."""
    return {name: rig_scatter(path) for name, path in SCENARIO_CONFIGS.items()}
