"""Configuration sources chosen in the rig config: file, operator, command, simulator, camera (lazy)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from rig.analysis.replay_run import replay
from rig.errors import ConfigError, InputError, RigError
from rig.hw.configuration import factory
from rig.hw.configuration.file_source import FileConfigurationSource, MeasuredAnglesFile
from rig.hw.configuration.operator_source import OperatorConfigurationSource, parse_angles_deg
from rig.hw.seams import MeasurementRequest
from rig.inputs.rig_config import DEFAULT_RIG_CONFIG, configuration_source_kind, parse_rig_config
from rig.log.format import schemas
from rig.sim.virtual_clock import VirtualClock
from rig.vocabulary import ConfigurationSourceKind
from tests.helpers import bare_protocol, shipped_block

ROOT = Path(__file__).resolve().parent.parent
LENGTHS = (0.03, 0.03, 0.03)


def request(index: int | None, after_slip: bool = False) -> MeasurementRequest:
    return MeasurementRequest(index, None, after_slip, lambda: None)


def config(**overrides: object) -> object:
    data = yaml.safe_load(DEFAULT_RIG_CONFIG.read_text())
    data.update(overrides)
    return data


# --- the rig config ---------------------------------------------------------------------------
def test_the_default_source_is_the_simulator_when_simulated_and_the_command_on_hardware() -> None:
    simulated = parse_rig_config(config(), source="r.yaml")
    assert configuration_source_kind(simulated) == ConfigurationSourceKind.SIMULATOR
    hardware = yaml.safe_load((ROOT / "protocols/rigs/hardware.example.yaml").read_text())
    parsed = parse_rig_config(hardware, source="h.yaml")
    assert configuration_source_kind(parsed) == ConfigurationSourceKind.COMMAND


@pytest.mark.parametrize(
    ("section", "message"),
    [
        ({"source": "file"}, "r.yaml: configuration.file: required with source: file"),
        (
            {"source": "camera", "camera": "c.yaml"},
            "r.yaml: configuration.markers: required with source: camera",
        ),
        ({"source": "webcam"}, "r.yaml: configuration.source"),
        ({"source": "operator", "device": 64}, "r.yaml: configuration.device"),
        ({"source": "operator", "colour": 1}, "colour"),
    ],
)
def test_a_bad_configuration_section_names_the_field(section: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        parse_rig_config(config(configuration=section), source="r.yaml")


def test_the_simulator_source_needs_a_simulated_rig() -> None:
    hardware = yaml.safe_load((ROOT / "protocols/rigs/hardware.example.yaml").read_text())
    hardware["configuration"] = {"source": "simulator"}
    with pytest.raises(ConfigError, match=r"configuration\.source: simulator needs kind: simulated"):
        parse_rig_config(hardware, source="h.yaml")


@pytest.mark.parametrize(
    ("ids", "message"),
    [
        ([{"id": 1, "role": "winch", "component": 1}], "component is for benders only"),
        (
            [{"id": 1, "role": "winch"}, {"id": 2, "role": "bender", "component": 9}],
            "component 9; allowed: 1..8",
        ),
        (
            [
                {"id": 1, "role": "winch"},
                {"id": 2, "role": "bender", "component": 1},
                {"id": 3, "role": "bender"},
            ],
            "every bender names its component or none",
        ),
        (
            [
                {"id": 1, "role": "winch"},
                {"id": 2, "role": "bender", "component": 2},
                {"id": 3, "role": "bender", "component": 2},
            ],
            "at most one fork",
        ),
    ],
)
def test_fork_components_are_checked(ids: list, message: str) -> None:
    data = config()
    data["servos"]["ids"] = ids
    with pytest.raises(ConfigError, match=message):
        parse_rig_config(data, source="r.yaml")


# --- file ---------------------------------------------------------------------------------------
def test_a_yaml_file_gives_each_configuration_its_angles(tmp_path: Path) -> None:
    path = tmp_path / "measured.yaml"
    path.write_text(
        "format: rig-configurations/1\nsd_deg: 0.5\nangles_deg:\n  1: [1, 2, 3]\n  2: [-4, 0, 90]\n"
    )
    source = FileConfigurationSource(MeasuredAnglesFile.load(path, 3), LENGTHS, VirtualClock())
    source.prepare(request(2))
    reading = source.measure()
    assert reading.joint_angles_rad == pytest.approx(np.radians([-4, 0, 90]))
    assert reading.uncertainty_rad == pytest.approx((math.radians(0.5),) * 3)
    assert reading.transforms.shape == (3, 4, 4)
    source.prepare(request(3))
    with pytest.raises(InputError, match=r"measured.yaml: configuration 3: not in the file; it lists 1, 2"):
        source.measure()


def test_a_csv_file_gives_each_configuration_its_angles(tmp_path: Path) -> None:
    path = tmp_path / "measured.csv"
    path.write_text("configuration,joint_1_deg,joint_2_deg,joint_3_deg\n# a comment\n1,1.5,-2,0\n")
    table = MeasuredAnglesFile.load(path, 3)
    assert table.angles_rad[1] == pytest.approx(np.radians([1.5, -2, 0]))
    assert table.sd_rad is None


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        (
            "m.csv",
            "configuration,joint_1_deg\n1,2\n",
            "header: expected configuration,joint_1_deg,joint_2_deg",
        ),
        ("m.csv", "configuration,joint_1_deg,joint_2_deg\n1,2\n", "row 2: 2 columns"),
        ("m.csv", "configuration,joint_1_deg,joint_2_deg\n1,2,x\n", "row 2: not a number"),
        ("m.csv", "configuration,joint_1_deg,joint_2_deg\n1,2,95\n", r"row 2: joint 2: 95 is out of range"),
        ("m.csv", "configuration,joint_1_deg,joint_2_deg\n1,2,3\n1,2,3\n", "configuration 1 is listed twice"),
        ("m.yaml", "format: other\n", "format: expected rig-configurations/1"),
        (
            "m.yaml",
            "format: rig-configurations/1\nangles_deg: {1: [1]}\n",
            r"angles_deg.1: 1 angles; allowed: 2",
        ),
        ("m.yaml", "format: rig-configurations/1\nangles_deg: {1: [1, 2]}\nsd_deg: -1\n", "sd_deg"),
    ],
)
def test_a_bad_file_is_an_input_error_naming_the_file_and_row(
    tmp_path: Path, name: str, text: str, message: str
) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(InputError, match=message) as caught:
        MeasuredAnglesFile.load(path, 2)
    assert str(caught.value).startswith(str(path))


# --- operator -----------------------------------------------------------------------------------
def test_typed_angles_are_checked_against_the_joint_count_and_range() -> None:
    assert parse_angles_deg("1, -2 3.5", 3)[0] == pytest.approx(np.radians([1, -2, 3.5]))
    assert "2 angles" in (parse_angles_deg("1 2", 3)[1] or "")
    assert "out of range" in (parse_angles_deg("1 2 91", 3)[1] or "")
    assert "not a number" in (parse_angles_deg("1 2 x", 3)[1] or "")


class _Terminal:
    """A pipe that says it is a terminal (select works on it)."""

    def __init__(self, text: str) -> None:
        read_fd, write_fd = os.pipe()
        os.write(write_fd, text.encode())
        os.close(write_fd)
        self._file = os.fdopen(read_fd)

    def isatty(self) -> bool:
        return True

    def fileno(self) -> int:
        return self._file.fileno()

    def readline(self) -> str:
        return self._file.readline()


def test_the_operator_is_asked_again_until_the_angles_are_valid_then_which_joint_moved(capsys) -> None:
    terminal = _Terminal("1 2\n1 2 3\n7\n2\n")
    source = OperatorConfigurationSource(LENGTHS, VirtualClock(), stdin=terminal, stderr=sys.stderr)  # type: ignore[arg-type]
    source.prepare(request(4))
    reading = source.measure()
    assert reading.joint_angles_rad == pytest.approx(np.radians([1, 2, 3]))
    source.prepare(request(4, after_slip=True))
    assert source.measure().slipped_joint == 2  # "7" was refused: only joints 1..3
    err = capsys.readouterr().err
    assert "configuration 4" in err and "refused: 2 angles" in err and "refused: '7'" in err


def test_the_operator_source_without_a_terminal_is_a_clear_error() -> None:
    class NoTerminal:
        def isatty(self) -> bool:
            return False

    source = OperatorConfigurationSource(LENGTHS, VirtualClock(), stdin=NoTerminal())  # type: ignore[arg-type]
    with pytest.raises(InputError, match="needs a person at a terminal"):
        source.measure()


# --- camera (the optional extra, imported lazily) ------------------------------------------------
def test_the_camera_source_is_imported_only_when_chosen_and_missing_it_is_a_clear_error(
    tmp_path: Path, monkeypatch
) -> None:
    data = config(
        configuration={"source": "camera", "camera": "cal.yaml", "markers": "map.yaml", "device": 3}
    )
    parsed = parse_rig_config(data, source=str(tmp_path / "r.yaml"), base_dir=tmp_path)
    monkeypatch.setattr(factory, "CAMERA_PACKAGE", "rig_no_such_camera_package")
    with pytest.raises(ConfigError, match=r"configuration\.source: camera needs the camera extra"):
        factory.hardware_configuration_source(parsed, VirtualClock())
    # With the extra (here a stand-in): device, calibration and marker map as the config names them.
    source = types.ModuleType("fake_camera.source")
    source.CameraDevice = lambda index: ("device", index)  # type: ignore[attr-defined]
    source.CameraConfigurationSource = lambda *args: ("source", args)  # type: ignore[attr-defined]
    calibration = types.ModuleType("fake_camera.camera_calibration")
    calibration.load_calibration = lambda path: ("calibration", path)  # type: ignore[attr-defined]
    marker_map = types.ModuleType("fake_camera.marker_map")
    marker_map.load_marker_map = lambda path: ("markers", path)  # type: ignore[attr-defined]
    for module in (types.ModuleType("fake_camera"), source, calibration, marker_map):
        monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setattr(factory, "CAMERA_PACKAGE", "fake_camera")
    clock = VirtualClock()
    made = factory.hardware_configuration_source(parsed, clock)
    assert made == (
        "source",
        (("device", 3), ("calibration", tmp_path / "cal.yaml"), ("markers", tmp_path / "map.yaml"), clock),
    )


def test_the_real_camera_package_has_every_module_the_factory_imports(tmp_path: Path) -> None:
    """With the extra installed, the imports succeed: what fails next is the device or the config's files."""
    pytest.importorskip("cv2")
    data = config(
        configuration={"source": "camera", "camera": "cal.yaml", "markers": "map.yaml", "device": 3}
    )
    parsed = parse_rig_config(data, source=str(tmp_path / "r.yaml"), base_dir=tmp_path)
    with pytest.raises(RigError) as raised:
        factory.hardware_configuration_source(parsed, VirtualClock())  # no camera 3, no cal.yaml
    assert "needs the camera extra" not in str(raised.value)


# --- a run: every measurement on its topic, the prediction from the measurement ---------------------
PROTOCOL = bare_protocol(
    "lv_small",
    [
        shipped_block("smoke", distances_m=[0.06, 0.12, 0.2], steps=None),
        shipped_block(
            "link_validation", 1, configurations_deg=[[10, -10, 5, 0, -5, 10, -10, 5], [-15, 15] * 4]
        ),
    ],
    ramp={"max_force_n": 70.0},
    limits={"force_ceiling_n": 75.0},
)


def _run(tmp_path: Path, rig: Path) -> tuple[dict, list[dict], list[dict]]:
    protocol = tmp_path / "lv.yaml"
    protocol.write_text(PROTOCOL)
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "rig.cli", "run", str(protocol), "--rig", str(rig), "--devices", "object",
         "--out", str(out), "--json"],
        capture_output=True, text=True, check=False, cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    measured, results = [], []
    with next(out.glob("*.mcap")).open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            if channel.topic == schemas.CONFIGURATION_MEASURED:
                measured.append(json.loads(message.data))
            elif channel.topic == schemas.TRIAL_RESULT:
                results.append(json.loads(message.data))
    return summary, measured, results


@pytest.mark.slow
def test_a_fork_run_logs_each_measurement_beside_the_commanded_angles_and_predicts_from_it(
    tmp_path: Path,
) -> None:
    _, measured, results = _run(tmp_path, ROOT / "protocols/rigs/forks-link1.yaml")
    bent = [m for m in measured if m["stage"] == "bent"]
    assert {m["trial_id"] for m in bent} == {4, 5}
    for trial in (4, 5):
        mine = [m for m in bent if m["trial_id"] == trial]
        assert [m["attempt"] for m in mine] == list(range(len(mine)))
        last = mine[-1]
        assert last["source"] == "simulator" and len(last["uncertainty_rad"]) == 8
        commanded = np.array(last["commanded_angles_rad"])
        angles = np.array(last["joint_angles_rad"])
        assert 0 < np.abs(angles - commanded).max() < math.radians(3)
        result = next(r for r in results if r["trial_id"] == trial)
        assert result["joint_angles_rad"] == pytest.approx(last["joint_angles_rad"])
    # Replay reads the measurements: where each trial's angles came from and after how many corrections.
    table = replay(tmp_path / "out").table
    assert list(table["configuration_source"].fillna("none")) == ["none"] * 3 + ["simulator"] * 2
    corrections = [int(m["attempt"]) for m in bent if m["trial_id"] == 5][-1]
    assert table["bend_corrections"].iloc[4] == corrections


@pytest.mark.slow
def test_with_the_command_source_nothing_is_measured_and_the_commanded_angles_stand_in(
    tmp_path: Path,
) -> None:
    rig = tmp_path / "rig.yaml"
    rig.write_text(
        (ROOT / "protocols/rigs/forks-link1.yaml").read_text() + "configuration:\n  source: command\n"
    )
    _, measured, results = _run(tmp_path, rig)
    assert measured == []
    result = next(r for r in results if r["trial_id"] == 4)
    assert result["joint_angles_rad"] == pytest.approx(np.radians([10, -10, 5, 0, -5, 10, -10, 5]))
