"""Pure physics and estimation for the preloaded spherical-joint link (SI units, no I/O, no clock)."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "capacity_grid_filter",
    "chain",
    "design",
    "field_spec",
    "fit",
    "fit_keys",
    "gravity",
    "joint",
    "joint_rotation",
    "k_estimators",
    "online_fit",
    "payload_errors",
    "slip_detector",
    "slipped_joint",
]
