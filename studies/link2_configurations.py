"""The 25 link-2 configurations of protocols/link_validation_link2.yaml, sampled uniformly.

Each of the 10 joint angles is drawn uniformly in [-20, 20] degrees (the span of link 1's shipped
configurations) from numpy's generator seeded with 2, rounded to 0.1 degree. The paper says its
25 configurations "represent a uniform sampling in the configuration space"; it does not list them.

    python studies/link2_configurations.py     # prints the YAML list
"""

from __future__ import annotations

import numpy as np

JOINTS = 10
CONFIGURATIONS = 25
SPAN_DEG = 20.0
SEED = 2


def configurations_deg() -> list[list[float]]:
    """The sampled configurations, joint 1 (base) first."""
    rng = np.random.default_rng(SEED)
    draws = rng.uniform(-SPAN_DEG, SPAN_DEG, size=(CONFIGURATIONS, JOINTS))
    return [[round(float(a), 1) for a in row] for row in draws]


if __name__ == "__main__":
    for row in configurations_deg():
        print("      - [" + ", ".join(f"{a:g}" for a in row) + "]")
