"""`rig replay`: exact reproduction of a fresh run, re-detection, damaged and resumed logs, the report."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.image import imread
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import breakup_chunk

from model.chain import lever_arms_m, planar_transforms
from rig.analysis import redetect as rd
from rig.analysis import report as report_module
from rig.analysis.replay_run import replay
from rig.analysis.trials import load_trial_table
from rig.cli import main
from rig.inputs.rig_config import load_rig_config
from rig.log.format import schemas as S
from rig.log.reading.reader import RunLog, read_run
from tests.helpers import link_small_protocol

PROTOCOLS = Path(__file__).resolve().parent.parent / "protocols"

LINK = link_small_protocol()

REPORT_FILES = (
    "report.md",
    "replay.json",
    "fit.png",
    "residuals.png",
    "payload_by_configuration.png",
    "percentage_errors.png",
    "estimate_evolution.png",
    "force_traces.png",
    "trials.csv",
    "trials.parquet",
)


HAIR_TRIGGER = ["cusum_threshold_n=0.001", "cusum_drift_n_per_s=0", "min_drop_n=0"]


class _InterruptAtTrial2:
    """The simulated person, who stops the run at trial 2's prompt."""

    def __init__(self, person) -> None:
        self.person = person

    def confirm(self, request, keep_alive):
        if request.trial is not None and request.trial.trial_id == 2:
            raise KeyboardInterrupt
        self.person.confirm(request, keep_alive)


@pytest.fixture(scope="session")
def logs(tmp_path_factory, run_on_simulated_rig):
    """A smoke run, a small link-validation run, and a smoke run interrupted then resumed."""

    def run(out: Path, protocol: Path, run_id: str, *, resume: bool = False, operator=None):
        def use_operator(sim) -> None:
            sim.session.operator = operator(sim.session.operator)

        patch = use_operator if operator is not None else None
        return run_on_simulated_rig(protocol, out, run_id=run_id, resume=resume, patch=patch)[0]

    root = tmp_path_factory.mktemp("replay_logs")
    smoke = run(root / "smoke", PROTOCOLS / "smoke.yaml", "smoke")
    link_protocol = root / "link_small.yaml"
    link_protocol.write_text(LINK)
    link = run(root / "link", link_protocol, "link")
    first = run(root / "resumed", PROTOCOLS / "smoke.yaml", "res", operator=_InterruptAtTrial2)
    resumed = run(root / "resumed", PROTOCOLS / "smoke.yaml", "res", resume=True)
    assert smoke.exit_code == 0 and link.exit_code == 0 and first.exit_code == 130 and resumed.exit_code == 0
    return {"root": root, "smoke": smoke, "link": link, "resumed": resumed}


@pytest.fixture
def replay_json(run_cli):
    """`replay_json(*argv)` -> (exit code, parsed stdout) of `rig replay ... --json`."""

    def replay_cli(*argv: str) -> tuple[int, dict]:
        result = run_cli("replay", *argv, "--json")
        return result.code, result.data

    return replay_cli


# ---------------------------------------------------------------------------------------------
# A fresh run is reproduced exactly


def test_fresh_run_reproduces_online_estimate_and_slip_events(logs, replay_json):
    code, out = replay_json(logs["smoke"].log)
    assert code == 0
    assert out["complete"] is True and out["warnings"] == []
    assert out["files"] == [logs["smoke"].log]
    assert [t["trial_id"] for t in out["trials"]] == [1, 2]
    online, offline = out["online_estimate"], out["estimate"]
    assert offline["n"] == online["n"] == 2
    for key in ("k", "sse", "sst", "r2", "rmse", "se", "capacity_nm", "mu_delta0_pa"):
        assert offline[key] == pytest.approx(online[key], rel=1e-9, abs=0)
    for key in ("k_ci", "capacity_ci_nm", "mu_delta0_ci_pa"):
        assert offline[key] == pytest.approx(online[key], rel=1e-9, abs=0)
    assert out["online_agreement"] == {
        "compared": True, "agree": True, "max_relative_difference": 0.0, "differing": []
    }  # fmt: skip
    # The run's own report (from its journal) is the same fit.
    assert offline["k"] == logs["smoke"].estimate.k
    redetection = out["redetection"]
    assert redetection["matches"] == 2 and redetection["mismatches"] == [] and redetection["exact"]
    assert out["redetected_estimate"] == offline
    for trial, logged in zip(out["trials"], logs["smoke"].as_json()["trials"], strict=True):
        assert trial["redetection"] == "match"
        assert trial["redetected_peak_force_n"] == trial["peak_force_n"] == logged["peak_force_n"]
        assert trial["slip_mass_kg"] == logged["slip_mass_kg"]
        assert trial["redetected_detection_time_ns"] == trial["slip_detection_time_ns"]
        assert trial["redetected_peak_time_ns"] == trial["slip_peak_time_ns"]
        assert trial["distance_m"] == logged["distance_m"] and trial["outcome"] == "slip"
    assert "percentage_errors" not in out  # no link validation in this run


def test_every_redetected_event_equals_the_logged_one_field_by_field(logs):
    result = replay(logs["link"].log)
    assert [r.status for r in result.redetections] == [rd.MATCH] * 4
    for found in result.redetections:
        assert found.logged is not None and found.event is not None and found.samples > 100
        for name in ("onset_time_ns", "detection_time_ns", "peak_time_ns", "peak_force_n", "force_after_n"):
            assert getattr(found.event, name) == getattr(found.logged, name)


def test_link_validation_tables_iv_and_v(logs, replay_json):
    code, out = replay_json(logs["link"].log)
    assert code == 0 and out["complete"]
    run_trials = logs["link"].as_json()["trials"]
    link_trials = [t for t in out["trials"] if t["kind"] == "link_validation"]
    assert len(link_trials) == 2 and [t["configuration_index"] for t in link_trials] == [1, 2]
    for t, logged in zip(link_trials, run_trials[2:], strict=True):
        assert t["predicted_mass_kg"] == logged["predicted_mass_kg"]
        assert t["percentage_error_pct"] == pytest.approx(logged["percentage_error"], rel=1e-12)
        assert t["joint_angles_rad"] == logged["joint_angles_rad"]
    pe = out["percentage_errors"]
    assert pe == logs["link"].percentage_errors.to_dict() | {"trial_ids": [3, 4]}
    # Table V: the base moment at slip is the peak tension times the line's lever arm about the
    # base origin at the measured configuration (rig geometry, computed here independently).
    article = load_rig_config(None).article
    expected = []
    for logged in run_trials[2:]:
        transforms = planar_transforms(
            np.array(logged["joint_angles_rad"]), np.array(article.segment_lengths_m)
        )
        arm = lever_arms_m(transforms, np.array(article.point_m), np.array(article.direction))[0]
        assert 0.2 < arm <= 0.27 + 1e-12  # a bent 8 x 30 mm link, loaded 30 mm past the tip
        expected.append(logged["peak_force_n"] * arm)
    bm = out["base_moments"]
    assert [t["base_moment_nm"] for t in bm["trials"]] == pytest.approx(expected, rel=1e-12)
    assert bm["mean_nm"] == pytest.approx(np.mean(expected), rel=1e-12)
    assert bm["std_nm"] == pytest.approx(np.std(expected, ddof=1), rel=1e-12)
    assert len(out["joints"]) == 8 and out["truth"]["capacity_nm"] > 0


# ---------------------------------------------------------------------------------------------
# Re-detection with other parameters


def test_redetection_parameters_move_the_peaks_the_expected_way(logs):
    logged = replay(logs["link"].log)
    base = logged.table.set_index("trial_id")
    # A hair-trigger detector fires on the first noise wiggle of the ramp: earlier, lower peaks. (The
    # percentage drop compares two-sample levels, so the hair trigger is a CUSUM of single decrements.)
    eager = replay(logs["link"].log, HAIR_TRIGGER).table.set_index("trial_id")
    assert (eager["redetected_detection_time_ns"] <= base["slip_detection_time_ns"]).all()
    assert (eager["redetected_peak_force_n"] <= base["peak_force_n"]).all()
    assert (eager["redetected_peak_force_n"] < base["peak_force_n"] - 0.5).any()
    assert set(eager["redetection"]) <= {rd.CHANGED, rd.MATCH}
    # A detector that needs a larger drop fires later (or not at all): peaks can only grow.
    patient = replay(logs["link"].log, ["drop_fraction=0.19"])
    table = patient.table.set_index("trial_id")
    found = table["redetected_peak_force_n"].notna()
    assert (
        table.loc[found, "redetected_detection_time_ns"] >= base.loc[found, "slip_detection_time_ns"]
    ).all()
    assert (table.loc[found, "redetected_peak_force_n"] >= base.loc[found, "peak_force_n"]).all()
    assert patient.detector.drop_fraction == 0.19 and patient.detector.arm_threshold_n == 1.0
    # The refit uses the re-detected peaks.
    eager_result = replay(logs["link"].log, HAIR_TRIGGER)
    assert eager_result.redetected_estimate.fit.k < eager_result.estimate.fit.k
    assert eager_result.redetection_summary().source == "command line"


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("drop_fractio=0.2", "unknown field 'drop_fractio'"),
        ("drop_fraction=1.5", "drop_fraction"),
        ("min_drop_n=abc", "min_drop_n"),
        ("drop_fraction", "key=value"),
    ],
)
def test_bad_detector_override_exits_2_naming_it(logs, capsys, tmp_path, override, message):
    report = tmp_path / "report"
    code = main(["replay", logs["smoke"].log, "--report", str(report), "--detector", override])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not report.exists()


# ---------------------------------------------------------------------------------------------
# Damaged, cut and resumed logs


def _results_in_intact_chunks(path: Path, cut: int, broken: set[int] = frozenset()) -> list[int]:
    """Trial ids of /rig/trial/result messages in chunks wholly before byte `cut` (not in `broken`),
    read with the plain mcap library from the intact original."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        topics = {cid: ch.topic for cid, ch in summary.channels.items()}
        ids = []
        for index in summary.chunk_indexes:
            if index.chunk_start_offset + index.chunk_length > cut or index.chunk_start_offset in broken:
                continue
            f.seek(index.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(io.BytesIO(f.read(index.chunk_length - 9))))
            for record in breakup_chunk(chunk):
                topic = topics.get(getattr(record, "channel_id", None))
                if topic == "/rig/trial/result" and hasattr(record, "data"):
                    ids.append(json.loads(record.data)["trial_id"])
    return sorted(ids)


def test_log_cut_at_70_percent_replays_every_trial_before_the_cut(logs, tmp_path, capsys, replay_json):
    source = Path(logs["link"].log)
    data = source.read_bytes()
    cut = int(len(data) * 0.7)
    damaged = tmp_path / "cut.mcap"
    damaged.write_bytes(data[:cut])
    expected = _results_in_intact_chunks(source, cut)
    assert 0 < len(expected) < 4
    code, out = replay_json(str(damaged))
    assert code == 0
    assert out["complete"] is False and any("no footer" in w for w in out["warnings"])
    assert [t["trial_id"] for t in out["trials"]] == expected
    full = {t["trial_id"]: t for t in replay(source).as_json()["trials"]}
    for trial in out["trials"]:
        assert trial["peak_force_n"] == full[trial["trial_id"]]["peak_force_n"]
    # Human output works on the damaged file too and says so.
    assert main(["replay", str(damaged)]) == 0
    text = capsys.readouterr().out
    assert "INCOMPLETE" in text and "warning:" in text


def test_corrupted_chunk_is_skipped_with_a_warning(logs, tmp_path, replay_json):
    source = Path(logs["link"].log)
    with open(source, "rb") as f:
        indexes = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    # Corrupt the chunk holding the first trial's result (the first chunk closed by a trial-end flush).
    target = next(
        i for i in indexes if _results_in_intact_chunks(source, i.chunk_start_offset + i.chunk_length)
    )
    data = bytearray(source.read_bytes())
    middle = target.chunk_start_offset + target.chunk_length // 2
    data[middle : middle + 16] = bytes(b ^ 0xFF for b in data[middle : middle + 16])
    damaged = tmp_path / "corrupt.mcap"
    damaged.write_bytes(bytes(data))
    code, out = replay_json(str(damaged))
    assert code == 0 and out["complete"] is False
    assert any(f"chunk at byte {target.chunk_start_offset}" in w for w in out["warnings"])
    expected = _results_in_intact_chunks(source, len(data), {target.chunk_start_offset})
    assert [t["trial_id"] for t in out["trials"]] == expected and 1 not in expected


def test_resumed_run_parts_combine(logs, replay_json):
    resumed = logs["resumed"]
    assert len(resumed.logs) == 2
    code, out = replay_json(str(Path(resumed.log).parent))
    assert code == 0 and out["complete"]
    assert out["files"] == resumed.logs  # run order: the first invocation's file, then part 2
    assert [t["trial_id"] for t in out["trials"]] == [1, 2]
    assert [t["part"] for t in out["trials"]] == [Path(p).name for p in resumed.logs]
    # The parts' virtual clocks both start at the same epoch: re-detection must keep them apart.
    assert out["redetection"]["matches"] == 2
    assert out["online_agreement"]["agree"] is True and out["estimate"]["n"] == 2
    assert out["estimate"]["k"] == resumed.estimate.k
    # The same files given one by one, in any order, give the same replay.
    code, again = replay_json(*reversed(resumed.logs))
    assert code == 0 and again["trials"] == out["trials"]


# ---------------------------------------------------------------------------------------------
# The report


@pytest.mark.slow
def test_report_has_every_file_and_round_trips_the_table(logs, tmp_path, replay_json):
    report = tmp_path / "nested" / "report"
    code, out = replay_json(logs["link"].log, "--report", str(report))
    assert code == 0
    assert sorted(p.name for p in report.iterdir()) == sorted(REPORT_FILES)
    assert sorted(Path(p).name for p in out["report"]) == sorted(REPORT_FILES)
    assert not [p for p in report.parent.iterdir() if p.name != "report"]  # no staging left
    for name in REPORT_FILES:
        if name.endswith(".png"):
            image = imread(report / name)
            height, width = image.shape[:2]
            assert height >= 300 and width >= 500, name
            assert float(np.std(image[..., :3])) > 0.05, f"{name} looks blank"
    markdown = (report / "report.md").read_text()
    for name in REPORT_FILES:
        if name.endswith(".png"):
            assert f"]({name})" in markdown
    assert "Table IV" in markdown and "Table V" in markdown
    result = replay(logs["link"].log)
    for name in ("trials.csv", "trials.parquet"):
        pd.testing.assert_frame_equal(load_trial_table(report / name), result.table, check_exact=True)
    raw = pd.read_parquet(report / "trials.parquet")
    assert (
        list(raw["trial_id"]) == [1, 2, 3, 4]
        and raw["peak_force_n"].tolist() == result.table["peak_force_n"].tolist()
    )
    assert json.loads((report / "replay.json").read_text())["estimate"] == out["estimate"]


@pytest.mark.slow
def test_report_without_link_validation_leaves_out_its_figures(logs, tmp_path, capsys):
    report = tmp_path / "smoke_report"
    report.mkdir()  # an empty directory is accepted
    assert main(["replay", logs["smoke"].log, "--report", str(report)]) == 0
    names = {p.name for p in report.iterdir()}
    assert {"fit.png", "residuals.png", "force_traces.png", "trials.csv"} <= names
    assert "percentage_errors.png" not in names
    assert "not drawn" in (report / "report.md").read_text()


@pytest.mark.slow
def test_a_long_run_gets_its_force_traces_in_pages(logs, tmp_path, monkeypatch):
    monkeypatch.setattr(report_module, "TRACES_PER_PAGE", 3)
    result = replay(logs["link"].log)
    written = report_module.write_report(result, tmp_path / "paged")
    pages = ["force_traces_1.png", "force_traces_2.png"]
    assert [p.name for p in written if p.name.startswith("force_traces")] == pages
    markdown = (tmp_path / "paged" / "report.md").read_text()
    assert "](force_traces.png)" not in markdown
    assert "(trials 1 to 3)" in markdown and "(trials 4 to 4)" in markdown
    for name in pages:
        assert f"]({name})" in markdown
    # 3 trials on the first page (one row of 3), 1 on the second: the first page is wider.
    first, second = (imread(tmp_path / "paged" / name) for name in pages)
    assert first.shape[1] > second.shape[1] and float(np.std(second[..., :3])) > 0.05


# ---------------------------------------------------------------------------------------------
# Memory: the samples are read one trial at a time


def test_replay_and_report_read_the_samples_one_trial_at_a_time(logs, tmp_path, monkeypatch):
    """No whole high-rate topic is decoded: each read is a trial's span, a fraction of the run."""
    windows: list[tuple[str, int]] = []
    window, topic = RunLog.window, RunLog.topic

    def counted_window(self, name, first_ns, last_ns):
        frame = window(self, name, first_ns, last_ns)
        windows.append((name, len(frame)))
        return frame

    def no_whole_samples(self, name):
        assert name not in (S.LOADCELL, S.SERVO_STATE), f"{name} read whole"
        return topic(self, name)

    monkeypatch.setattr(RunLog, "window", counted_window)
    monkeypatch.setattr(RunLog, "topic", no_whole_samples)
    # Other detector parameters: the winch states are read per trial too.
    result = replay(logs["link"].log, ["drop_fraction=0.2"])
    report_module.write_report(result, tmp_path / "report")
    counts = read_run(logs["link"].log, topics=()).message_counts
    for name in (S.LOADCELL, S.SERVO_STATE):
        sizes = [n for topic_name, n in windows if topic_name == name]
        # 4 trials: 4 reads for the replay (and 4 more of load-cell samples for the figure)
        assert len(sizes) == (8 if name == S.LOADCELL else 4)
        assert 0 < max(sizes) < counts[name] / 2, (name, sizes, counts[name])


# ---------------------------------------------------------------------------------------------
# Bad inputs


def test_bad_inputs_exit_2_with_one_line_and_leave_nothing(logs, tmp_path, capsys):
    report = tmp_path / "r"
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("hello, not an mcap file\n")
    empty_dir = tmp_path / "empty"
    empty_dir.mkdir()
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "keep.txt").write_text("x")
    cases = [
        ([str(tmp_path / "missing.mcap")], "no such file"),
        ([str(not_mcap)], "not an MCAP file"),
        ([str(empty_dir)], "no .mcap files"),
        ([logs["smoke"].log, "--report", str(occupied)], "not empty"),
    ]
    for argv, message in cases:
        extra = [] if "--report" in argv else ["--report", str(report)]
        code = main(["replay", *argv, *extra])
        err = capsys.readouterr().err
        assert code == 2, argv
        assert message in err and len(err.strip().splitlines()) == 1, err
        assert not report.exists()
    assert [p.name for p in occupied.iterdir()] == ["keep.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "notes.mcap", "occupied"]


def test_an_mcap_without_rig_topics_is_refused(tmp_path, capsys):
    from mcap.writer import Writer

    path = tmp_path / "other.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        channel = writer.register_channel("/other", "json", 0)
        writer.add_message(channel, 1, b"{}", 1)
        writer.finish()
    assert main(["replay", str(path)]) == 2
    assert "no rig topics" in capsys.readouterr().err
