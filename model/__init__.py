"""Pure physics and estimation for the preloaded spherical-joint link (SI units, no I/O, no clock)."""

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
__all__ = [
    "chain",
    "design",
    "estimate_summary",
    "estimators",
    "field_spec",
    "fit",
    "gravity",
    "joint",
    "joint_capacity_estimation",
    "joint_rotation",
    "online_fit",
    "payload_errors",
    "slip_detector",
    "slipped_joint",
]
