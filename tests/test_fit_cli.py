"""`rig fit DATA.csv`: JSON contract, agreement with an independent fit, human output, bad input."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from rig.cli import main

REPO = Path(__file__).resolve().parents[1]
RIG = Path(sys.executable).with_name("rig")
DESIGN_KEYS = [
    "n", "k", "k_ci", "sse", "sst", "r2", "rmse", "dfe", "se", "level", "constant", "c", "radius_m",
    "mu_delta0_pa", "mu_delta0_ci_pa", "capacity_nm", "capacity_ci_nm",
]  # fmt: skip


def independent(distances, masses, level, radius, c, g):
    """numpy lstsq on the column 1/l and scipy's t: no code shared with model.fit."""
    x = 1.0 / np.asarray(distances)
    m = np.asarray(masses)
    (k,), *_ = np.linalg.lstsq(x[:, None], m, rcond=None)
    res = m - k * x
    sse = float(res @ res)
    sst = float(((m - m.mean()) ** 2).sum())
    dfe = len(m) - 1
    rmse = math.sqrt(sse / dfe)
    se = rmse / math.sqrt(float(x @ x))
    t = stats.t.ppf((1 + level) / 2, dfe)
    k_ci = [k - t * se, k + t * se]
    scale = g / (c * radius**3)
    return {
        "n": len(m), "k": k, "k_ci": k_ci, "sse": sse, "sst": sst, "r2": 1 - sse / sst, "rmse": rmse,
        "dfe": dfe, "se": se, "level": level, "radius_m": radius, "mu_delta0_pa": k * scale,
        "mu_delta0_ci_pa": [v * scale for v in k_ci], "capacity_nm": k * g,
        "capacity_ci_nm": [v * g for v in k_ci],
    }  # fmt: skip


def assert_matches(summary, ref, rel=1e-9):
    for key, expected in ref.items():
        assert summary[key] == pytest.approx(expected, rel=rel), key


@pytest.mark.parametrize("seed", range(8))
def test_json_agrees_with_an_independent_fit(seed, write_file, cli_json):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(2, 30))
    distances = rng.uniform(0.03, 0.5, n)
    masses = np.abs(0.2 / distances + rng.normal(0, 0.1, n))
    use_force = seed % 2 == 1
    g = 9.81 if use_force else 9.8
    values = masses * g if use_force else masses
    column = "force_n" if use_force else "mass_kg"
    rows = "".join(
        f"{float(d)!r},{float(v)!r},trial-{i}\n"
        for i, (d, v) in enumerate(zip(distances, values, strict=True))
    )
    path = write_file(f"distance_m,{column},note\n{rows}", "data.csv")
    level = [0.9, 0.95, 0.99][seed % 3]
    constant, c = [("paper", 5.4397), ("derived", math.pi**2), ("7.5", 7.5)][seed % 3]
    summary = cli_json(
        "fit",
        path,
        "--radius-m",
        0.012,
        "--constant",
        constant,
        "--level",
        level,
        "--g",
        g,
        "--estimator",
        "paper",
        "--json",
        quiet=True,
    )
    assert list(summary)[: len(DESIGN_KEYS)] == DESIGN_KEYS
    ref_masses = values / g if use_force else masses
    reference = independent(distances, ref_masses, level, 0.012, c, g)
    assert_matches(summary, reference)
    assert summary["estimator"] == "paper" and summary["paper"] == {k: summary[k] for k in DESIGN_KEYS}
    assert summary["constant"] == {"paper": "paper", "derived": "derived"}.get(constant, "custom")
    assert summary["c"] == pytest.approx(c, rel=1e-15)


def test_model_vector_9_through_the_cli(write_file, cli_json):
    path = write_file("distance_m,mass_kg\n0.1,1.7\n0.2,0.78\n0.4,0.41\n0.5,0.33\n", "data.csv")
    summary = cli_json(
        "fit",
        path,
        "--radius-m",
        "0.01",
        "--constant",
        "derived",
        "--estimator",
        "paper",
        "--json",
        quiet=True,
    )
    assert summary["k"] == pytest.approx(0.16698706, rel=1e-6)
    assert summary["sse"] == pytest.approx(0.00399723, rel=1e-6)
    assert summary["sst"] == pytest.approx(1.1833, rel=1e-6)
    assert summary["r2"] == pytest.approx(0.99662197, rel=1e-6)
    assert summary["rmse"] == pytest.approx(0.03650218, rel=1e-6)
    assert summary["se"] == pytest.approx(0.00313870, rel=1e-6)
    assert summary["k_ci"] == pytest.approx([0.14865418, 0.18531994], rel=1e-6)
    assert summary["dfe"] == 3 and summary["n"] == 4 and summary["level"] == 0.99


@pytest.mark.slow
@pytest.mark.subprocess
def test_subprocess_of_the_installed_console_script():
    example = REPO / "protocols" / "example_fit.csv"
    proc = subprocess.run(
        [str(RIG), "fit", str(example), "--radius-m", "0.01", "--json"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert list(summary)[: len(DESIGN_KEYS)] == DESIGN_KEYS and summary["estimator"] == "auto"
    rows = [line.split(",") for line in example.read_text().splitlines() if line and line[0].isdigit()]
    distances = [float(r[0]) for r in rows]
    masses = [float(r[1]) for r in rows]
    assert_matches(summary["paper"], independent(distances, masses, 0.99, 0.01, 5.4397, 9.8))
    assert summary["constant"] == "paper"


def test_all_equal_masses_print_null_r2(capsys, write_file, cli_json):
    path = write_file("distance_m,mass_kg\n0.1,0.5\n0.2,0.5\n0.3,0.5\n", "data.csv")
    summary = cli_json("fit", path, "--radius-m", "0.01", "--json", quiet=True)
    assert summary["r2"] is None and summary["sst"] == 0.0
    assert main(["fit", str(path), "--radius-m", "0.01"]) == 0
    assert "undefined (all masses equal)" in capsys.readouterr().out


def test_human_output_is_a_table_with_units(capsys):
    code = main(["fit", str(REPO / "protocols" / "example_fit.csv"), "--radius-m", "0.01"])
    out = capsys.readouterr().out
    assert code == 0
    for needle in ("kg·m", "kg²", "R²", "RMSE", "dfe", "se(k)", "Pa", "N·m", "99 % bounds", "(paper)",
                   "t(0.995, 7)", "c = 5.4397"):  # fmt: skip
        assert needle in out, needle
    k_line = next(line for line in out.splitlines() if line.startswith("k "))
    assert "[" in k_line and "kg·m" in k_line


def test_comments_blank_lines_bom_and_spaces_are_accepted(write_file, cli_json):
    text = "\ufeff# rig 2 joint 3\n\n distance_m , mass_kg \n# repeat\n0.1, 1.7\n\n0.2 ,0.78\n0.4,0.41\n"
    text += "0.5,0.33\n"
    path = write_file(text, "data.csv")
    summary = cli_json("fit", path, "--radius-m", "0.01", "--estimator", "paper", "--json", quiet=True)
    assert summary["n"] == 4 and summary["k"] == pytest.approx(0.16698706, rel=1e-6)


BAD_FILES = [
    ("empty", "", "data.csv: the file is empty; allowed: a header line naming distance_m and mass_kg"),
    ("comments-only", "# nothing\n\n", "the file is empty"),
    ("misspelt-distance", "distanse_m,mass_kg\n0.1,1\n0.2,0.5\n",
     "data.csv: line 1: missing column 'distance_m' (found 'distanse_m', 'mass_kg'). Did you mean "
     "'distance_m' instead of 'distanse_m'? Allowed columns: distance_m and mass_kg (or force_n"),
    ("misspelt-mass", "distance_m,mass_kgs\n0.1,1\n0.2,0.5\n",
     "missing column 'mass_kg' or 'force_n' (found 'distance_m', 'mass_kgs'). Did you mean 'mass_kg'"),
    ("no-mass", "distance_m,weight\n0.1,1\n0.2,0.5\n",
     "missing column 'mass_kg' or 'force_n' (found 'distance_m', 'weight'). Allowed"),
    ("both", "distance_m,mass_kg,force_n\n0.1,1,9.8\n0.2,0.5,4.9\n", "both 'mass_kg' and 'force_n'"),
    ("duplicate", "distance_m,mass_kg,mass_kg\n0.1,1,1\n0.2,0.5,0.5\n", "column 'mass_kg' appears twice"),
    ("non-numeric", "distance_m,mass_kg\n0.1,1\n0.2,abc\n",
     "data.csv: data row 2 (line 3): column 'mass_kg': 'abc' is not a number; allowed: a decimal number"),
    ("empty-cell", "# c\ndistance_m,mass_kg\n0.1,1\n,0.5\n",
     "data row 2 (line 4): column 'distance_m': an empty cell is not a number"),
    ("zero-distance", "distance_m,mass_kg\n0.1,1\n0,0.5\n",
     "data row 2 (line 3): column 'distance_m': 0.0; allowed: 0.0001 to 100 m"),
    ("negative-distance", "distance_m,mass_kg\n-0.1,1\n0.2,0.5\n",
     "data row 1 (line 2): column 'distance_m': -0.1"),
    ("nan", "distance_m,mass_kg\n0.1,nan\n0.2,0.5\n",
     "column 'mass_kg': 'nan'; allowed: a finite number 0 to 10000 kg"),
    ("negative-force", "distance_m,force_n\n0.1,-1\n0.2,0.5\n",
     "column 'force_n': -1.0; allowed: 0 or 1e-09 to 100000 N"),
    ("tiny-distance", "distance_m,mass_kg\n1e-320,1\n0.2,0.5\n",
     "column 'distance_m': 1e-320; allowed: 0.0001"),
    ("tiny-mass", "distance_m,mass_kg\n0.1,1e-320\n0.2,0.5\n",
     "column 'mass_kg': 1e-320; allowed: 0 or 1e-09"),
    ("huge-mass", "distance_m,mass_kg\n0.1,1e300\n0.2,0.5\n",
     "column 'mass_kg': 1e+300; allowed: 0 or 1e-09"),
    ("one-row", "distance_m,mass_kg\n0.1,1\n",
     "data.csv: 1 data row(s) after the header; allowed: at least 2"),
    ("ragged", "distance_m,mass_kg\n0.1,1\n0.2,0.5,7\n",
     "data row 2 (line 3): 3 fields but the header (line 1) has 2"),
]  # fmt: skip


@pytest.mark.parametrize(("text", "message"), [b[1:] for b in BAD_FILES], ids=[b[0] for b in BAD_FILES])
def test_bad_files_exit_2_with_one_line(capsys, text, message, write_file):
    path = write_file(text, "data.csv")
    code = main(["fit", str(path), "--radius-m", "0.01", "--json"])
    out, err = capsys.readouterr()
    assert code == 2
    assert out == ""
    assert err.count("\n") == 1 and "Traceback" not in err
    assert message in err, err
    assert str(path) in err


BAD_OPTIONS = [
    ("radius-zero", ["--radius-m", "0"], "--radius-m 0: allowed: a number from 1e-05 to 1 [m], e.g. 0.01"),
    ("radius-negative", ["--radius-m", "-0.01"], "--radius-m -0.01: allowed"),
    ("radius-text", ["--radius-m", "big"], "--radius-m 'big' is not a number"),
    ("level-1", ["--radius-m", "0.01", "--level", "1"],
     "--level 1: allowed: a number from 0.001 to 0.999999, e.g. 0.99"),
    ("level-99", ["--radius-m", "0.01", "--level", "99"], "--level 99"),
    ("constant", ["--radius-m", "0.01", "--constant", "papr"],
     "--constant 'papr': allowed: paper (5.4397), derived"),
    ("constant-negative", ["--radius-m", "0.01", "--constant", "-3"], "--constant '-3'"),
    ("radius-subnormal", ["--radius-m", "1e-320"], "--radius-m 1e-320: allowed: a number from 1e-05"),
    ("level-nan", ["--radius-m", "0.01", "--level", "nan"], "--level nan: allowed"),
    ("constant-huge", ["--radius-m", "0.01", "--constant", "1e300"], "--constant '1e300': allowed"),
    ("g", ["--radius-m", "0.01", "--g", "0"], "--g 0: allowed: a number from 0.1 to 100 [m/s²]"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("options", "message"), [b[1:] for b in BAD_OPTIONS], ids=[b[0] for b in BAD_OPTIONS]
)
def test_bad_options_exit_2_with_one_line(capsys, options, message, write_file):
    path = write_file("distance_m,mass_kg\n0.1,1.7\n0.2,0.78\n", "data.csv")
    code = main(["fit", str(path), *options])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "Traceback" not in err
    assert message in err, err


def test_missing_file_and_missing_radius(tmp_path, capsys):
    assert main(["fit", str(tmp_path / "nope.csv"), "--radius-m", "0.01"]) == 2
    assert "nope.csv: file not found" in capsys.readouterr().err
    with pytest.raises(SystemExit) as excinfo:
        main(["fit", str(tmp_path / "nope.csv")])
    assert excinfo.value.code == 2
    assert "--radius-m" in capsys.readouterr().err


@pytest.mark.subprocess
def test_subprocess_bad_input_has_no_traceback(write_file):
    path = write_file("distance_m,mass_kg\n0.1,1\n0,0.5\n", "data.csv")
    proc = subprocess.run(
        [str(RIG), "fit", str(path), "--radius-m", "0.01"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.startswith("rig: error: ") and proc.stderr.count("\n") == 1


# Degenerate fits (docs/model.md §4, "Degenerate fits"): the JSON numbers stay cftool's, the result
# says why the fit is degenerate, and no bound is printed below 0.
FLAT = "distance_m,mass_kg\n0.05,2.0\n0.10,2.0\n0.20,2.00001\n"  # R² = -4e10: no fall with distance
ONE_DISTANCE = "distance_m,mass_kg\n0.1,1.6\n0.1,1.7\n0.1,1.5\n"
TWO_POINTS = "distance_m,mass_kg\n0.1,1.6\n0.2,0.7\n"  # sound, but t(0.995, 1) = 63.7


def _bounds_cells(out):
    """Every bounds cell '[lo, hi]' of the tables, as the two texts."""
    cells = [line[line.index("[") + 1 : line.index("]")] for line in out.splitlines() if "[" in line]
    return [part.strip() for cell in cells for part in cell.split(",")]


@pytest.mark.parametrize(
    ("text", "reason"),
    [(FLAT, "do not fall with distance as 1/l"), (ONE_DISTANCE, "every slip is at one distance (0.1 m)")],
)
def test_a_degenerate_fit_says_so(write_file, cli_json, capsys, text, reason):
    path = write_file(text, "data.csv")
    summary = cli_json("fit", path, "--radius-m", "0.01", "--estimator", "paper", "--json", quiet=True)
    (said,) = summary["degenerate"]
    assert reason in said
    assert main(["fit", str(path), "--radius-m", "0.01", "--estimator", "paper"]) == 0
    out = capsys.readouterr().out
    assert f"DEGENERATE FIT: {said}" in out
    assert all(not cell.startswith("-") for cell in _bounds_cells(out)), out


def test_flat_masses_keep_cftools_numbers_in_json_but_print_no_negative_bound(write_file, cli_json, capsys):
    path = write_file(FLAT, "data.csv")
    summary = cli_json("fit", path, "--radius-m", "0.01", "--estimator", "paper", "--json", quiet=True)
    assert summary["r2"] == pytest.approx(-4.00004e10, rel=1e-5)  # cftool's R², as computed
    assert summary["capacity_ci_nm"][0] < 0  # the t interval as computed (the JSON contract)
    assert main(["fit", str(path), "--radius-m", "0.01"]) == 0  # the default estimator, auto
    out = capsys.readouterr().out
    assert "(degenerate)" in next(line for line in out.splitlines() if line.startswith("R²"))
    assert all(not cell.startswith("-") for cell in _bounds_cells(out)), out


def test_two_points_show_bounds_cut_at_zero_with_a_note(write_file, cli_json, capsys):
    path = write_file(TWO_POINTS, "data.csv")
    summary = cli_json("fit", path, "--radius-m", "0.01", "--json", quiet=True)
    assert summary["degenerate"] == [] and summary["paper"]["capacity_ci_nm"][0] < 0
    assert main(["fit", str(path), "--radius-m", "0.01", "--estimator", "paper"]) == 0
    out = capsys.readouterr().out
    capacity = next(line for line in out.splitlines() if line.startswith("capacity N_max"))
    assert "[0*, " in capacity and "DEGENERATE" not in out
    assert "* the 99 % t interval on k reaches below 0 (its lower end -0.353254 kg·m, dfe = 1)" in out


def test_a_sound_fit_prints_as_before(capsys, cli_json):
    data = REPO / "protocols" / "example_fit.csv"
    assert cli_json("fit", data, "--radius-m", "0.01", "--json", quiet=True)["degenerate"] == []
    assert main(["fit", str(data), "--radius-m", "0.01"]) == 0
    out = capsys.readouterr().out
    assert "DEGENERATE" not in out and "*" not in out


def test_a_reader_that_goes_away_leaves_no_traceback():
    # `rig fit ... | head -1`: the pipe's reader is gone before rig writes (closed at once here).
    example = Path(__file__).resolve().parent.parent / "protocols" / "example_fit.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rig.cli", "fit", str(example), "--radius-m", "0.01"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 1
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
