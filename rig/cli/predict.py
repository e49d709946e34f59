"""`rig predict LINK.yaml`: joint moments, slip load, first joint to slip and link capacity of a link file."""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from model.chain import SlipPrediction, joint_moment_norms, predict_slip
from rig.cli.commands import COMMANDS
from rig.cli.output import emit_json, format_table
from rig.inputs.linkfile import LinkSpec, load_link_file

DESCRIPTION = """\
Predict, from the static model (docs/model.md §3), the moment each joint of a link must hold,
the load at which the first joint slips, which joint that is, and the link's capacity.

The link file (YAML, SI units) lists the joints from the base to the tip and the tip load:

  g: 9.8                                  # optional
  joints:                                 # joint i: ball of component i in the socket of i-1
    - transform: [[1,0,0,0],[0,1,0,0],[0,0,1,0.03],[0,0,0,1]]   # pose of {i} in {i-1}
      capacity_nm: 1.2                    # N_max [N·m]
    - xyz: [0, 0, 0.03]                   # or a pose as xyz [m] + rpy [rad],
      rpy: [0, 0.5236, 0]                 #   R = Rz(yaw)·Ry(pitch)·Rx(roll)
      radius_m: 0.01                      # or N_max = c·mu_s·delta0·R³ from R and
      mu_delta0_pa: 1.6e5                 #   mu_s·delta0 [Pa], c = paper (default),
      constant: derived                   #   derived (pi²) or a number
  load:
    point_m: [0, 0, 0.03]                 # acting point Q in the tip frame
    direction: [0, -1, 0]                 # load direction, base frame; or force_n: [fx, fy, fz]

With `direction`, joint moments are reported at the slip load; with `force_n`, under that force
(and the slip load is along its direction). A commented example: protocols/example_link.yaml.
"""

EPILOG = """\
JSON (--json): joint_moments_nm (joint 1 nearest the base), base_moment_nm (about the base
origin, same load), slip_force_n, slip_mass_kg, first_slip_joint (1-based), tip_moment_nm (the
tip joint's moment at slip: the link capacity). A joint on the load's line of action never slips;
if all are, the slip values are null. Exit codes: 0 done, 2 invalid link file.
"""


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add `rig predict`."""
    parser = subparsers.add_parser(
        "predict",
        help=COMMANDS["predict"],
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "link", metavar="LINK.yaml", help="link file (see above, or protocols/example_link.yaml)"
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout and nothing else"
    )
    parser.set_defaults(handler=run)


def _moments_nm(spec: LinkSpec, prediction: SlipPrediction) -> np.ndarray:
    """‖N_0‖..‖N_J‖ under the file's force, or at the slip load when it gives a direction."""
    if spec.force_n is not None:
        return joint_moment_norms(spec.transforms, spec.point_m, spec.force_n)
    return prediction.joint_moments_at_slip_nm


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def result_dict(spec: LinkSpec, prediction: SlipPrediction) -> dict[str, Any]:
    """The `--json` object of docs/formats.md §3 (exactly these keys)."""
    moments = _moments_nm(spec, prediction)
    slips = int(prediction.first_slip_joint) > 0
    return {
        "joint_moments_nm": [float(m) for m in moments[1:]],
        "base_moment_nm": _finite_or_none(float(moments[0])),
        "slip_force_n": _finite_or_none(float(prediction.slip_force_n)),
        "slip_mass_kg": _finite_or_none(float(prediction.slip_mass_kg)),
        "first_slip_joint": int(prediction.first_slip_joint) if slips else None,
        "tip_moment_nm": float(prediction.tip_moment_nm) if slips else None,
    }


def _report(spec: LinkSpec, prediction: SlipPrediction) -> str:
    moments = _moments_nm(spec, prediction)
    arms = prediction.lever_arms_m
    under = "under force_n" if spec.force_n is not None else "at slip load"
    rows: list[list[Any]] = [["base", float(arms[0]), None, float(moments[0]), None, "", ""]]
    for i in range(1, spec.n_joints + 1):
        capacity = float(spec.capacities_nm[i - 1])
        marks = []
        if int(prediction.first_slip_joint) == i:
            marks.append("slips first")
        elif bool(prediction.tied_joints[i - 1]):
            marks.append("tied")
        if arms[i] == 0:
            marks.append("on load line")
        rows.append(
            [
                str(i),
                float(arms[i]),
                capacity,
                float(moments[i]),
                f"{100.0 * float(moments[i]) / capacity:.1f} %",
                ", ".join(marks),
                spec.capacity_sources[i - 1].describe(),
            ]
        )
    headers = [
        "joint",
        "lever arm [m]",
        "capacity [N·m]",
        f"moment {under} [N·m]",
        "utilisation",
        "",
        "capacity from",
    ]
    lines = [f"Link {spec.source}: {spec.n_joints} joints, g = {spec.g:g} m/s²", ""]
    lines.append(format_table(headers, rows))
    lines.append("")
    direction = ", ".join(f"{v:.6g}" for v in spec.direction_w)
    point = ", ".join(f"{v:.6g}" for v in spec.point_m)
    lines.append(f"load direction (base frame):  ({direction}) at Q = ({point}) m in the tip frame")
    if int(prediction.first_slip_joint) == 0:
        lines.append("every joint lies on the load's line of action: no load along it makes the link slip")
        return "\n".join(lines)
    lines += [
        f"slip load:                    {float(prediction.slip_force_n):.6g} N "
        f"({float(prediction.slip_mass_kg):.6g} kg at g = {spec.g:g} m/s²)",
        f"first joint to slip:          joint {int(prediction.first_slip_joint)}",
        f"link capacity (tip moment):   {float(prediction.tip_moment_nm):.6g} N·m",
        f"base moment at slip:          {float(prediction.base_moment_nm):.6g} N·m",
    ]
    if spec.force_n is not None:
        magnitude = float(np.linalg.norm(spec.force_n))
        factor = float(prediction.slip_force_n) / magnitude
        verdict = "tolerated" if factor >= 1.0 else "NOT tolerated (a joint slips)"
        lines.append(f"applied force {magnitude:.6g} N:   {verdict}; slip load / applied = {factor:.4g}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Load the link file, predict, print a table or one JSON object."""
    spec = load_link_file(args.link)
    prediction = predict_slip(spec.transforms, spec.capacities_nm, spec.point_m, spec.direction_w, g=spec.g)
    if args.json:
        emit_json(result_dict(spec, prediction))
    else:
        print(_report(spec, prediction))
    return 0
