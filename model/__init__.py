"""Pure physics and estimation for the preloaded spherical-joint link (SI units, no I/O, no clock)."""

from model.chain import forward_kinematics, planar_transforms, predict_slip
from model.fit import fit_inverse_distance, fit_summary
from model.fit_keys import summarize_estimate
from model.k_estimators import estimate_k
from model.slip_detector import DetectorParams, SlipEvent, detect_slips

# The modules other packages may import; the others are private to this package
# (import-linter contract "private modules stay private", pyproject.toml).
PUBLIC_MODULES = (
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
)

# The names users import (`from model import estimate_k`).
__all__ = [
    "DetectorParams",
    "SlipEvent",
    "detect_slips",
    "estimate_k",
    "fit_inverse_distance",
    "fit_summary",
    "forward_kinematics",
    "planar_transforms",
    "predict_slip",
    "summarize_estimate",
]
