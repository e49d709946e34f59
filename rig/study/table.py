"""The study's Parquet table: one row per run x case x estimator, written atomically.

A case is a joint's fixed trials or one adaptive block's trials (`rig.study.series`); an adaptive
block's rows carry its number and why it stopped. An aborted run without results still gets one
row per estimator (NaN estimates, its reason), so the table has every seed. The file appears
whole or not at all: it is written to a temporary name in the same directory and renamed.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from rig.inputs.files import plain_file_mode
from rig.study.worker import RunRecord

TABLE_NAME = "study.parquet"

SCHEMA = pa.schema(
    [
        ("seed", pa.uint64()),
        ("status", pa.string()),  # completed | aborted
        ("reason", pa.string()),
        ("trials_planned", pa.int32()),
        ("trials_completed", pa.int32()),
        ("wall_s", pa.float64()),
        ("joint", pa.int32()),
        ("k_true_kg_m", pa.float64()),
        ("true_scatter_a_kg", pa.float64()),
        ("true_scatter_b", pa.float64()),
        ("n_slips", pa.int32()),
        ("n_censored", pa.int32()),
        ("n_excluded", pa.int32()),
        ("distances_m", pa.list_(pa.float64())),
        ("masses_kg", pa.list_(pa.float64())),  # the trials' slip masses, in the order of distances_m
        ("censored", pa.list_(pa.bool_())),  # no slip before the force limit: the mass is a lower bound
        ("crlb_var_kg2_m2", pa.float64()),
        ("estimator", pa.string()),
        ("k_kg_m", pa.float64()),
        ("k_low_kg_m", pa.float64()),
        ("k_high_kg_m", pa.float64()),
        ("se_kg_m", pa.float64()),
        ("n", pa.int32()),
        ("n_censored_used", pa.int32()),
        ("scatter_model", pa.string()),
        ("scatter_a_kg", pa.float64()),
        ("scatter_b", pa.float64()),
        ("estimator_error", pa.string()),
        ("covered", pa.bool_()),
        ("block", pa.int32()),  # the adaptive block of this case (null: the joint's fixed trials)
        ("stop_reason", pa.string()),  # why that block stopped: target_reached | budget | no_safe_distance
    ]
)


def table_rows(records: Sequence[RunRecord], estimator_names: Sequence[str]) -> list[dict[str, Any]]:
    """The rows of the table (see the module docstring)."""
    rows: list[dict[str, Any]] = []
    nan = math.nan
    for run in sorted(records, key=lambda r: r.seed):
        base = {
            "seed": run.seed,
            "status": run.status,
            "reason": run.reason,
            "trials_planned": run.trials_planned,
            "trials_completed": run.trials_completed,
            "wall_s": run.wall_s,
        }
        if not run.joints:
            for name in estimator_names:
                rows.append({**base, "estimator": name, "k_kg_m": nan, "covered": None})
            continue
        for joint in run.joints:
            joint_part = {
                "joint": joint.joint,
                "k_true_kg_m": joint.k_true_kg_m,
                "true_scatter_a_kg": joint.true_scatter_a_kg,
                "true_scatter_b": joint.true_scatter_b,
                "n_slips": joint.n_slips,
                "n_censored": joint.n_censored,
                "n_excluded": joint.n_excluded,
                "distances_m": list(joint.distances_m),
                "masses_kg": list(joint.masses_kg),
                "censored": list(joint.censored),
                "crlb_var_kg2_m2": joint.crlb_var,
                "block": joint.block,
                "stop_reason": None if joint.stop_reason is None else joint.stop_reason.value,
            }
            for e in joint.estimates:
                ok = e.error is None and math.isfinite(e.k)
                rows.append(
                    {
                        **base,
                        **joint_part,
                        "estimator": e.estimator,
                        "k_kg_m": e.k,
                        "k_low_kg_m": e.k_low,
                        "k_high_kg_m": e.k_high,
                        "se_kg_m": e.se,
                        "n": e.n,
                        "n_censored_used": e.n_censored,
                        "scatter_model": e.scatter_model,
                        "scatter_a_kg": e.scatter_a_kg,
                        "scatter_b": e.scatter_b,
                        "estimator_error": e.error,
                        "covered": (e.k_low <= joint.k_true_kg_m <= e.k_high) if ok else None,
                    }
                )
    return rows


def write_table(out_dir: Path, records: Sequence[RunRecord], estimator_names: Sequence[str]) -> Path:
    """Write `out_dir/study.parquet` atomically; returns its path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pylist(table_rows(records, estimator_names), schema=SCHEMA)
    target = out_dir / TABLE_NAME
    mode = plain_file_mode(target)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{TABLE_NAME}.", suffix=".tmp", dir=out_dir)
    os.fchmod(fd, mode)
    os.close(fd)
    try:
        pq.write_table(table, tmp_name)
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
        raise
    return target
