"""Load-cell calibration: math, JSON files, the operator procedure and `rig calibrate --sim`."""

import argparse
import json
import math

import pytest

from model.gravity import STANDARD_GRAVITY_M_S2
from rig.errors import InputError
from rig.hw.loadcell.calibration import (
    Calibration,
    CalibrationError,
    CalibrationStep,
    Reading,
    indicator_calibration,
    run_calibration,
    tare,
    two_point,
)
from rig.hw.seams import LoadCellSample
from rig.sim.loadcell.inprocess_line import simulated_load_cell
from rig.sim.loadcell.profiles import StepTension
from rig.sim.virtual_clock import VirtualClock

CAL = Calibration(
    factor_n_per_count=1.25e-5,
    offset_counts=120000.5,
    reference_mass_kg=1.0,
    g=9.80665,
    date="2026-03-01T10:00:00+00:00",
    serial="LC-0042",
    format="rig-lc1",
    noise_counts=400.0,
    temperature_c=21.5,
)


def test_force_conversion_and_tare():
    assert CAL.force_n(120000.5) == 0.0
    assert CAL.force_n(120000.5 + 80000) == pytest.approx(1.0)
    assert CAL.raw_for_force(2.0) == pytest.approx(120000.5 + 160000)
    assert CAL.noise_n == pytest.approx(0.005)
    assert CAL.with_tare(1000).force_n(1000) == 0.0 and CAL.with_tare(1000).factor_n_per_count == 1.25e-5
    samples = [LoadCellSample(0, raw, 0.0) for raw in (10, 12, 14)]
    assert tare(samples) == Reading(12.0, pytest.approx(math.sqrt(8 / 3)), 3)
    assert tare([5]) == Reading(5.0, 0.0, 1)
    with pytest.raises(CalibrationError, match="no load-cell samples"):
        tare([])


def test_two_point_by_hand():
    # zero at 1000 counts, 2 kg at 1000 + 39226.6 counts: factor = 2 * 9.80665 / 39226.6 = 0.0005 N/count
    cal = two_point(
        Reading(1000.0, 3.0, 500), Reading(40226.6, 4.0, 500), 2.0, serial="S1", format_name="rig-lc1"
    )
    assert cal.factor_n_per_count == pytest.approx(0.0005)
    assert cal.offset_counts == 1000.0 and cal.noise_counts == 3.0
    assert cal.force_n(40226.6) == pytest.approx(2 * STANDARD_GRAVITY_M_S2)
    # A cell wired so that tension reads negative gets a negative factor; forces stay positive.
    neg = two_point(Reading(0.0, 1.0, 10), Reading(-1000.0, 1.0, 10), 1.0)
    assert neg.factor_n_per_count < 0 and neg.force_n(-1000.0) == pytest.approx(STANDARD_GRAVITY_M_S2)
    with pytest.raises(CalibrationError, match=r"only 5\.0 counts"):
        two_point(Reading(0.0, 2.0, 10), Reading(5.0, 2.0, 10), 1.0)
    with pytest.raises(InputError, match="allowed: > 0"):
        two_point(Reading(0.0, 2.0, 10), Reading(5000.0, 2.0, 10), 0.0)


def test_indicator_calibration_units():
    assert indicator_calibration("kg", 2).force_n(123) == pytest.approx(1.23 * STANDARD_GRAVITY_M_S2)
    assert indicator_calibration("g", 0).force_n(500) == pytest.approx(0.5 * STANDARD_GRAVITY_M_S2)
    assert indicator_calibration("N", 1).force_n(-15) == pytest.approx(-1.5)
    assert indicator_calibration("lb", 0).force_n(1) == pytest.approx(0.45359237 * STANDARD_GRAVITY_M_S2)
    with pytest.raises(InputError, match="allowed"):
        indicator_calibration("oz")


def test_json_round_trip(tmp_path):
    path = tmp_path / "sub" / "cal.json"
    CAL.save(path)
    assert Calibration.load(path) == CAL
    data = json.loads(path.read_text())
    assert data["kind"] == "rig.loadcell.calibration" and data["version"] == 1
    assert not list(path.parent.glob(".*tmp"))  # no temporary file left behind
    minimal = {k: v for k, v in data.items() if k not in ("noise_counts", "temperature_c", "kind", "version")}
    minimal["reference_mass_kg"] = None
    path.write_text(json.dumps(minimal))
    loaded = Calibration.load(path)
    assert loaded.reference_mass_kg is None and loaded.noise_counts is None


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("{not json", "malformed JSON at line 1"),
        ("[1, 2]", "top level must be a JSON object"),
        ("MISSING:factor_n_per_count", "factor_n_per_count: missing"),
        (
            "SET:factor_n_per_count=0",
            "factor_n_per_count: 0; allowed: a finite number with 1e-12 <= |x| <= 1e+06",
        ),
        ("SET:factor_n_per_count=1e-320", "factor_n_per_count: 1e-320; allowed"),
        ("SET:offset_counts=1e300", "offset_counts: 1e+300; allowed: a finite number from -1e+12 to 1e+12"),
        ("SET:offset_counts=" + "9" * 400, "offset_counts: an integer beyond the float range; allowed"),
        ('SET:offset_counts="12"', "offset_counts: '12'; allowed: a finite number"),
        ("SET:g=-9.8", "g: -9.8; allowed: a finite number from 0.1 to 100"),
        ("SET:temperature_c=1000", "temperature_c: 1000; allowed: a finite number from -100 to 200"),
        ('SET:date="yesterday"', "date: 'yesterday'; allowed: an ISO 8601"),
        ("SET:serial=12", "serial: 12; allowed: a string"),
        ('SET:kind="other"', "kind: 'other'"),
        ("SET:version=2", "version: 2"),
        ("SET:noise_counts=-1", "noise_counts: -1; allowed: a finite number from 0 to 1e+12"),
        ('SET:serial="' + "x" * 300 + '"', "serial: 'xxxx"),
        ('{"kind": "rig.loadcell.calibration", "kind": "x"}', "duplicate key 'kind'"),
        ('{"factor_n_per_count": NaN}', "NaN is not a JSON number"),
        ("SET:reference_mass_kg=true", "reference_mass_kg: True; allowed: a finite number"),
    ],
)
def test_bad_files_name_file_and_field(tmp_path, text, match):
    path = tmp_path / "cal.json"
    data = CAL.to_dict()
    if text.startswith("MISSING:"):
        del data[text.split(":", 1)[1]]
        text = json.dumps(data)
    elif text.startswith("SET:"):
        field, value = text[4:].split("=", 1)
        data[field] = json.loads(value)
        text = json.dumps(data)
    path.write_text(text)
    with pytest.raises(InputError) as exc:
        Calibration.load(path)
    assert str(exc.value).startswith(str(path)) and match in str(exc.value)


def test_missing_file():
    with pytest.raises(InputError, match=r"nope\.json: file not found"):
        Calibration.load("/nonexistent/nope.json")


def test_run_calibration_against_the_simulated_cell():
    clock = VirtualClock()
    tension = StepTension(3.0)  # something is hanging before the operator starts
    load_cell, emulator = simulated_load_cell(tension, clock, rate_hz=1000, seed=4)
    steps = []

    def prompt(step, message):
        steps.append((step, message))
        tension.set(
            0.0 if step is CalibrationStep.REMOVE_LOAD else 0.5 * STANDARD_GRAVITY_M_S2, clock.monotonic_ns()
        )

    progress = []
    with load_cell:
        cal = run_calibration(
            load_cell,
            prompt,
            0.5,
            2.0,
            clock=clock,
            average_s=0.5,
            serial="X",
            format_name="rig-lc1",
            progress_fn=progress.append,
        )
    assert [s for s, _ in steps] == [CalibrationStep.REMOVE_LOAD, CalibrationStep.PLACE_REFERENCE]
    assert "0.5 kg" in steps[1][1]
    signal = emulator.signal
    assert cal.factor_n_per_count == pytest.approx(1 / signal.gain_counts_per_n, rel=2e-4)
    # The zero is averaged 2.0-2.5 s after start: the drift (5 counts/s) has added ~11 counts.
    assert cal.offset_counts == pytest.approx(signal.offset_counts + 11.25, abs=60)
    assert cal.noise_counts == pytest.approx(signal.noise_counts, rel=0.1)
    assert (cal.reference_mass_kg, cal.serial, cal.format) == (0.5, "X", "rig-lc1")
    assert any("averaging zero" in p for p in progress)


def test_run_calibration_aborted_by_operator_or_without_mass():
    clock = VirtualClock()
    load_cell, _ = simulated_load_cell(StepTension(0.0), clock)

    def abort(step, message):
        raise KeyboardInterrupt

    with load_cell, pytest.raises(KeyboardInterrupt):
        run_calibration(load_cell, abort, 1.0, 0.1, clock=clock)
    with load_cell, pytest.raises(CalibrationError, match="is the mass hanging"):
        run_calibration(load_cell, lambda step, message: None, 1.0, 0.1, clock=clock, average_s=0.2)


def cli(argv):
    from rig.cli import calibrate

    parser = argparse.ArgumentParser()
    calibrate.register(parser.add_subparsers())
    args = parser.parse_args(["calibrate", *argv])
    return args.handler(args)


def test_rig_calibrate_sim_yes_end_to_end(tmp_path, capsys):
    out = tmp_path / "cal.json"
    code = cli(
        ["--sim", "--yes", "--reference-kg", "2.0", "--out", str(out), "--serial", "SN7", "--settle-s", "1"]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "Step 1/2" in text and "Step 2/2" in text and "[auto-confirmed]" in text
    assert "N/count" in text and "noise at zero" in text and f"wrote {out}" in text
    cal = Calibration.load(out)
    assert cal.factor_n_per_count == pytest.approx(1 / 80_000, rel=2e-4)
    assert cal.noise_n == pytest.approx(0.005, rel=0.1)
    assert (cal.serial, cal.reference_mass_kg, cal.format) == ("SN7", 2.0, "rig-lc1")


def test_rig_calibrate_sim_json_and_indicator_format(tmp_path, capsys):
    out = tmp_path / "cal.json"
    code = cli(
        ["--sim", "--yes", "--format", "indicator-st", "--reference-kg", "1", "--out", str(out), "--json"]
    )
    assert code == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out)  # one JSON object and nothing else on stdout
    assert result["out"] == str(out) and result["format"] == "indicator-st"
    # The indicator shows kg with 2 decimals: 100 digits per kg -> 0.0980665 N per digit.
    assert result["factor_n_per_count"] == pytest.approx(STANDARD_GRAVITY_M_S2 / 100, rel=1e-3)
    assert "Step 1/2" in captured.err


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--reference-kg", "0"], "--reference-kg 0.0; allowed: > 0"),
        (["--reference-kg", "1", "--settle-s", "-1"], "--settle-s"),
        (["--reference-kg", "1", "--g", "1.6"], "--g 1.6; allowed: 9.7-9.9"),
        (["--reference-kg", "nan"], "--reference-kg nan"),
    ],
)
def test_rig_calibrate_rejects_bad_input_before_starting(tmp_path, argv, match):
    out = tmp_path / "cal.json"
    with pytest.raises(InputError, match=match):
        cli(["--sim", "--yes", "--out", str(out), *argv])
    assert not out.exists()


def test_rig_calibrate_interrupted_writes_nothing(tmp_path, monkeypatch):
    out = tmp_path / "cal.json"
    out.write_text("previous calibration")

    def interrupted(prompt=""):
        raise KeyboardInterrupt

    monkeypatch.setattr("builtins.input", interrupted)
    monkeypatch.setattr("sys.stdin.isatty", lambda: True, raising=False)
    with pytest.raises(KeyboardInterrupt):
        cli(["--sim", "--reference-kg", "1", "--out", str(out), "--force"])
    assert out.read_text() == "previous calibration"
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]


def test_rig_calibrate_stdin_closed_without_yes(tmp_path, monkeypatch):
    def closed(prompt=""):
        raise EOFError

    monkeypatch.setattr("builtins.input", closed)
    with pytest.raises(CalibrationError, match="use --yes"):
        cli(["--port", "loop://", "--reference-kg", "1", "--out", str(tmp_path / "c.json")])


def _existing_calibration(tmp_path):
    out = tmp_path / "cal.json"
    out.write_text("the calibration of last week")
    return out


def test_rig_calibrate_keeps_an_existing_calibration_without_a_terminal(tmp_path, run_cli, monkeypatch):
    out = _existing_calibration(tmp_path)
    monkeypatch.setattr("sys.stdin.isatty", lambda: False, raising=False)
    result = run_cli("calibrate", "--sim", "--yes", "--reference-kg", "1", "--out", out)
    assert result.code == 2 and result.err.count("\n") == 1 and "Traceback" not in result.err
    assert f"--out {out}: a calibration exists there and was kept; --force overwrites it" in result.err
    assert out.read_text() == "the calibration of last week"
    assert run_cli("calibrate", "--sim", "--yes", "--reference-kg", "1", "--out", out, "--force").code == 0
    assert Calibration.load(out).reference_mass_kg == 1.0


@pytest.mark.parametrize(("answer", "code"), [("n", 2), ("", 2), ("y", 0)])
def test_rig_calibrate_asks_before_overwriting_at_a_terminal(tmp_path, run_cli, monkeypatch, answer, code):
    out = _existing_calibration(tmp_path)
    questions = []

    def reply(prompt=""):
        questions.append(prompt)
        return answer

    monkeypatch.setattr("builtins.input", reply)
    monkeypatch.setattr("sys.stdin.isatty", lambda: True, raising=False)
    result = run_cli("calibrate", "--sim", "--yes", "--reference-kg", "1", "--out", out)
    assert result.code == code, result.err
    assert questions == [f"{out} holds a calibration already; overwrite it with the new one? [y/N] "]
    kept = out.read_text() == "the calibration of last week"
    assert kept == (code == 2)
