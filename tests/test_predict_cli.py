"""`rig predict`: docs/model.md §8 values via the CLI, human output, help, one-line errors for bad links."""

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from rig.cli import main
from rig.errors import InputError
from rig.inputs.linkfile import load_link_file, parse_link

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "protocols" / "example_link.yaml"
RIG = Path(sys.executable).with_name("rig")

VECTOR_4 = """\
joints:
  - {xyz: [0, 0, 0.03], rpy: [0, 0, 0], capacity_nm: %(c1)s}
  - {xyz: [0, 0, 0.03], rpy: [0, 0.5235987755982988, 0], capacity_nm: %(c2)s}
  - {xyz: [0, 0, 0.03], rpy: [0, -0.3490658503988659, 0], capacity_nm: %(c3)s}
load:
  point_m: [0, 0, 0.03]
  %(load)s
"""


def test_vector_6_through_cli(write_file, cli_json):
    path = write_file(
        VECTOR_4 % {"c1": 1.2, "c2": 0.9, "c3": 0.8, "load": "direction: [0, -1, 0]"}, "link.yaml"
    )
    out = cli_json("predict", path, "--json")
    assert out["slip_mass_kg"] == pytest.approx(1.3933610, rel=1e-6)
    assert out["first_slip_joint"] == 1


def test_vector_7_through_cli(write_file, cli_json):
    path = write_file(
        VECTOR_4 % {"c1": 2.0, "c2": 0.9, "c3": 0.8, "load": "direction: [0, -1, 0]"}, "link.yaml"
    )
    out = cli_json("predict", path, "--json")
    assert out["slip_force_n"] == pytest.approx(15.231399, rel=1e-6)
    assert out["slip_mass_kg"] == pytest.approx(1.5542244, rel=1e-6)
    assert out["first_slip_joint"] == 2
    assert out["tip_moment_nm"] == pytest.approx(0.4569420, rel=1e-6)
    assert out["base_moment_nm"] == pytest.approx(1.7863286, rel=1e-6)  # at the slip load
    assert out["joint_moments_nm"][1] == pytest.approx(0.9, rel=1e-12)  # joint 2 on its capacity


def test_vector_5_moments_under_force_n(write_file, cli_json):
    path = write_file(
        VECTOR_4 % {"c1": 2.0, "c2": 0.9, "c3": 0.8, "load": "force_n: [0, -9.8, 0]"}, "link.yaml"
    )
    out = cli_json("predict", path, "--json")
    assert out["base_moment_nm"] == pytest.approx(1.1493376, rel=1e-6)
    assert out["joint_moments_nm"] == pytest.approx([0.8612269, 0.5790670, 0.2940000], rel=1e-6)
    # The slip values do not depend on the magnitude of force_n, only its direction.
    assert out["slip_force_n"] == pytest.approx(15.231399, rel=1e-6)
    assert out["tip_moment_nm"] == pytest.approx(0.4569420, rel=1e-6)


def test_vector_8_single_joint(write_file, cli_json):
    text = "joints:\n  - {transform: [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], capacity_nm: 1}\n"
    text += "load: {point_m: [0, 0, 0.1], force_n: [2, 0, 0]}\n"
    out = cli_json("predict", write_file(text, "link.yaml"), "--json")
    assert out["joint_moments_nm"] == pytest.approx([0.2])
    assert out["base_moment_nm"] == pytest.approx(0.2)
    assert out["slip_force_n"] == pytest.approx(10.0)
    assert out["first_slip_joint"] == 1 and out["tip_moment_nm"] == pytest.approx(1.0)


def test_capacity_from_radius_and_mu_delta0(tmp_path, write_file, cli_json):
    # Vector 1: R = 0.01, mu_delta0 = 1e5 -> 0.98696044 N·m (derived), 0.54397 N·m (paper, default).
    base = "load: {point_m: [0, 0, 0.1], direction: [1, 0, 0]}\njoints:\n  - {xyz: [0,0,0], rpy: [0,0,0], "
    derived = cli_json(
        "predict",
        write_file(base + "radius_m: 0.01, mu_delta0_pa: 1.0e+5, constant: derived}\n", "link.yaml"),
        "--json",
    )
    assert derived["tip_moment_nm"] == pytest.approx(0.98696044, rel=1e-6)
    paper = cli_json(
        "predict",
        write_file(base + "radius_m: 0.01, mu_delta0_pa: 1e5}\n", "link.yaml"),
        "--json",
    )  # "1e5" is a str
    assert paper["tip_moment_nm"] == pytest.approx(0.54397, rel=1e-6)
    custom = cli_json(
        "predict",
        write_file(base + "radius_m: 0.01, mu_delta0_pa: 100000, constant: 2.0}\n", "link.yaml"),
        "--json",
    )
    assert custom["tip_moment_nm"] == pytest.approx(0.2, rel=1e-12)
    spec = load_link_file(tmp_path / "link.yaml")
    assert spec.capacity_sources[0].constant.name == "custom"
    assert spec.capacity_sources[0].kind == "radius_mu_delta0"


def test_example_file_and_human_output(capsys, cli_json):
    assert main(["predict", str(EXAMPLE)]) == 0
    out = capsys.readouterr().out
    assert "slips first" in out and "lever arm [m]" in out and "capacity [N·m]" in out
    assert "15.2314 N" in out and "1.55422 kg" in out and "joint 2" in out and "0.456942 N·m" in out
    assert "c=paper (5.4397)" in out  # joint 3's capacity says which constant made it
    assert "100.0 %" in out
    out = cli_json("predict", EXAMPLE, "--json")
    assert out["first_slip_joint"] == 2
    assert out["slip_force_n"] == pytest.approx(15.231399, rel=1e-6)


def test_human_output_under_force_says_whether_tolerated(capsys, write_file):
    ok = write_file(
        VECTOR_4 % {"c1": 2.0, "c2": 0.9, "c3": 0.8, "load": "force_n: [0, -9.8, 0]"}, "link.yaml"
    )
    assert main(["predict", str(ok)]) == 0
    out = capsys.readouterr().out
    assert "under force_n" in out and "tolerated" in out and "NOT" not in out
    heavy = write_file(
        VECTOR_4 % {"c1": 2.0, "c2": 0.9, "c3": 0.8, "load": "force_n: [0, -20, 0]"}, "link.yaml"
    )
    assert main(["predict", str(heavy)]) == 0
    assert "NOT tolerated" in capsys.readouterr().out


def test_nothing_slips_when_every_joint_is_on_the_load_line(capsys, write_file, cli_json):
    path = write_file(
        VECTOR_4 % {"c1": 2.0, "c2": 0.9, "c3": 0.8, "load": "direction: [0, 0, -1]"}, "link.yaml"
    )
    path.write_text(path.read_text().replace("0.5235987755982988", "0").replace("-0.3490658503988659", "0"))
    out = cli_json("predict", path, "--json")
    assert out["slip_force_n"] is None and out["first_slip_joint"] is None and out["tip_moment_nm"] is None
    assert out["joint_moments_nm"] == [0.0, 0.0, 0.0]
    assert main(["predict", str(path)]) == 0
    assert "no load along it makes the link slip" in capsys.readouterr().out


def test_help_teaches_the_format(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["predict", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for needle in (
        "capacity_nm",
        "xyz",
        "rpy",
        "radius_m",
        "mu_delta0_pa",
        "point_m",
        "force_n",
        "protocols/example_link.yaml",
        "first_slip_joint",
    ):
        assert needle in out


@pytest.mark.slow
@pytest.mark.subprocess
def test_installed_console_script(write_file):
    result = subprocess.run(
        [str(RIG), "predict", str(EXAMPLE), "--json"], capture_output=True, text=True, timeout=60, check=False
    )
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["tip_moment_nm"] == pytest.approx(0.4569420, rel=1e-6)
    bad = write_file("joints: []\nload: {point_m: [0,0,0], direction: [1,0,0]}\n", "link.yaml")
    result = subprocess.run(
        [str(RIG), "predict", str(bad)], capture_output=True, text=True, timeout=60, check=False
    )
    assert result.returncode == 2
    assert result.stdout == ""
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert str(bad) in result.stderr and "joints" in result.stderr


# ---------------------------------------------------------------- bad input: exit 2, one line, file and field

GOOD_JOINT = "{xyz: [0, 0, 0.03], rpy: [0, 0, 0], capacity_nm: 1.0}"
GOOD_LOAD = "load: {point_m: [0, 0, 0.03], direction: [0, -1, 0]}"


def link_with_joint(joint, load=GOOD_LOAD, extra=""):
    return f"{extra}joints:\n  - {GOOD_JOINT}\n  - {joint}\n{load}\n"


ROT = "[[1,0,0,0],[0,1,0,0],[0,0,1,0.03],[0,0,0,1]]"

BAD_INPUTS = [
    ("joints: [\n", "malformed YAML"),
    ("- 1\n- 2\n", "(top level)"),
    ("", "(top level)"),
    (f"{GOOD_LOAD}\n", "joints: missing"),
    (f"joints:\n  - {GOOD_JOINT}\n", "load: missing"),
    (link_with_joint(GOOD_JOINT, extra="colour: red\n"), "colour: unknown key"),
    ("joints: []\n" + GOOD_LOAD, "joints: [] is not a non-empty list"),
    ("joints: {a: 1}\n" + GOOD_LOAD, "joints: {'a': 1} is not a non-empty list"),
    (link_with_joint("5"), "joints[1]: 5 is not a mapping"),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], capacity_nm: 1, colour: 2}"),
        "joints[1].colour: unknown key",
    ),
    (link_with_joint("{transform: [[1,0,0],[0,1,0],[0,0,1]], capacity_nm: 1}"), "joints[1].transform"),
    (
        link_with_joint("{transform: [[1,0,0,0],[0,1,0,0],[0,0,1,x],[0,0,0,1]], capacity_nm: 1}"),
        "joints[1].transform[2][3]: 'x' is not a number",
    ),
    (
        link_with_joint("{transform: [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], capacity_nm: 1}"),
        "joints[1].transform: joint 2: not a rigid motion",
    ),
    (link_with_joint("{transform: [[1,0,0,0],[0,1,0,0],[0,0,-1,0],[0,0,0,1]], capacity_nm: 1}"), "det"),
    (link_with_joint("{transform: [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,1,1]], capacity_nm: 1}"), "bottom row"),
    (
        link_with_joint(f"{{transform: {ROT}, xyz: [0,0,0], rpy: [0,0,0], capacity_nm: 1}}"),
        "both `transform`",
    ),
    (link_with_joint("{capacity_nm: 1}"), "joints[1]: joint 2 gives no pose"),
    (link_with_joint("{xyz: [0,0,0], capacity_nm: 1}"), "joints[1].rpy: joint 2: missing"),
    (
        link_with_joint("{xyz: [0,0], rpy: [0,0,0], capacity_nm: 1}"),
        "joints[1].xyz: [0, 0] is not a list of 3",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,a,0], capacity_nm: 1}"),
        "joints[1].rpy[1]: 'a' is not a number",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,.nan,0], capacity_nm: 1}"),
        "joints[1].rpy[1]: nan is not finite",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], capacity_nm: 0}"),
        "joints[1].capacity_nm: 0 is not positive",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], capacity_nm: -2}"),
        "joints[1].capacity_nm: -2 is not posi",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], capacity_nm: true}"),
        "joints[1].capacity_nm: True is not a n",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], capacity_nm: abc}"),
        "joints[1].capacity_nm: 'abc' is not a",
    ),
    (link_with_joint("{xyz: [0,0,0], rpy: [0,0,0]}"), "joints[1].radius_m: joint 2: missing"),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], radius_m: 0.01}"),
        "joints[1].mu_delta0_pa: joint 2: missing",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], radius_m: 0, mu_delta0_pa: 1}"),
        "joints[1].radius_m: 0 is",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], radius_m: 0.01, mu_delta0_pa: -1}"),
        "joints[1].mu_delta0_pa",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], radius_m: 0.01, mu_delta0_pa: 1, constant: papr}"),
        "joints[1].constant: 'papr' is not a capacity constant; allowed: paper, derived or a number from",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], radius_m: 0.01, mu_delta0_pa: 1, constant: -3}"),
        "joints[1].constant",
    ),
    (
        link_with_joint("{xyz: [0,0,0], rpy: [0,0,0], capacity_nm: 1, constant: paper}"),
        "joints[1]: joint 2 gives both `capacity_nm` and `constant`",
    ),
    (link_with_joint(GOOD_JOINT, load="load: [1, 2]"), "load: [1, 2] is not a mapping"),
    (link_with_joint(GOOD_JOINT, load="load: {direction: [0, -1, 0]}"), "load.point_m: missing"),
    (
        link_with_joint(GOOD_JOINT, load="load: {point_m: [0, 0], direction: [0, -1, 0]}"),
        "load.point_m: [0, 0]",
    ),
    (link_with_joint(GOOD_JOINT, load="load: {point_m: [0, 0, 0]}"), "load: gives neither"),
    (
        link_with_joint(GOOD_JOINT, load="load: {point_m: [0,0,0], direction: [0,1,0], force_n: [0,1,0]}"),
        "load: gives both",
    ),
    (
        link_with_joint(GOOD_JOINT, load="load: {point_m: [0,0,0], direction: [0,0,0]}"),
        "load.direction: is the zero vector",
    ),
    (
        link_with_joint(GOOD_JOINT, load="load: {point_m: [0,0,0], force_n: [0,0,0]}"),
        "load.force_n: is the zero",
    ),
    (
        link_with_joint(GOOD_JOINT, load="load: {point_m: [0,0,0], direction: [0,1,0], mass: 1}"),
        "load.mass: unknown key",
    ),
    (link_with_joint(GOOD_JOINT, extra="g: 0\n"), "g: 0 is not positive"),
    (link_with_joint(GOOD_JOINT, extra="g: -9.8\n"), "g: -9.8 is not positive"),
    (link_with_joint(GOOD_JOINT, extra="g: heavy\n"), "g: 'heavy' is not a number"),
]


@pytest.mark.parametrize(("text", "expected"), BAD_INPUTS)
def test_bad_link_file_exits_2_with_one_line(capsys, text, expected, write_file):
    path = write_file(text, "bad_link.yaml")
    code = main(["predict", str(path), "--json"])
    captured = capsys.readouterr()
    assert code == 2
    assert captured.out == ""
    err = captured.err
    assert err.count("\n") == 1, err
    assert "Traceback" not in err
    assert err.startswith(f"rig: error: {path}: ")
    assert expected in err
    if expected != "malformed YAML":
        assert "allowed:" in err


def test_missing_file_exits_2(tmp_path, capsys):
    assert main(["predict", str(tmp_path / "nope.yaml")]) == 2
    err = capsys.readouterr().err
    assert "nope.yaml: file not found" in err and err.count("\n") == 1


def test_parse_link_with_prefix_for_rig_configs():
    data = {"joints": [{"xyz": [0, 0, 0.03], "rpy": [0, 0, 0], "capacity_nm": -1}], "load": {}}
    with pytest.raises(
        InputError, match=r"^rig\.yaml: article\.joints\[0\]\.capacity_nm: -1 is not positive"
    ):
        parse_link(data, "rig.yaml", field_prefix="article.")
    good = {
        "joints": [{"xyz": [0, 0, 0.03], "rpy": [0, 0, 0], "capacity_nm": 1}],
        "load": {"point_m": [0, 0, 0.03], "direction": [0, -2, 0]},
    }
    spec = parse_link(good, "rig.yaml", field_prefix="article.")
    assert spec.n_joints == 1 and spec.g == 9.8 and spec.force_n is None
    assert spec.direction_w.tolist() == [0.0, -1.0, 0.0]  # normalised
    assert spec.transforms.shape == (1, 4, 4) and not spec.transforms.flags.writeable
    assert math.isclose(spec.transforms[0, 2, 3], 0.03)
    assert spec.capacity_sources[0].kind == "capacity_nm" and spec.capacity_sources[0].constant is None
