import os
import stat

import pytest

from rig.errors import InputError
from rig.hw.loadcell.calibration import Calibration
from rig.inputs.files import (
    MAX_NESTING,
    MAX_YAML_BYTES,
    atomic_write_text,
    load_yaml_file,
    parse_json,
    parse_yaml,
    read_text_file,
)
from rig.runner.runlock import RunLock


def test_read_text_file_reads_utf8_and_drops_a_byte_order_mark(tmp_path):
    path = tmp_path / "a.txt"
    path.write_bytes("\ufeffμ = 0.5\n".encode())
    assert read_text_file(path) == "μ = 0.5\n"


def _binary(directory):
    path = directory / "bin.csv"
    path.write_bytes(b"\xff\xfe\x00")
    return path


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda d: d / "nope.csv", r"nope\.csv: file not found$"),
        (lambda d: d, r": is a directory; allowed: a CSV file$"),
        (_binary, r"bin\.csv: not UTF-8 text \(byte 0xff at line 1\); allowed: a CSV file$"),
    ],
)
def test_read_text_file_errors_name_the_file_and_what_is_allowed(tmp_path, make, message):
    with pytest.raises(InputError, match=message):
        read_text_file(make(tmp_path), what="a CSV file")


def test_load_yaml_file_names_the_file_and_the_place(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("a: [1, 2\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"bad\.yaml: malformed YAML at line 2, column 1"):
        load_yaml_file(path)
    with pytest.raises(InputError, match=r"gone\.yaml: file not found"):
        load_yaml_file(tmp_path / "gone.yaml")


def test_only_regular_files_of_bounded_size_are_read(tmp_path):
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)  # opening it would block until a writer comes
    with pytest.raises(InputError, match=r"fifo\.yaml: not a regular file \(a FIFO, device or socket\)"):
        read_text_file(fifo)
    with pytest.raises(InputError, match=r"^/dev/zero: not a regular file"):
        read_text_file("/dev/zero")
    big = tmp_path / "big.csv"
    big.write_bytes(b"0" * 101)
    with pytest.raises(InputError, match=r"big\.csv: larger than 100 bytes; allowed: a CSV file"):
        read_text_file(big, what="a CSV file", max_bytes=100)
    assert read_text_file(big, max_bytes=101) == "0" * 101


def test_yaml_size_is_bounded(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text("a: [" + "1, " * (MAX_YAML_BYTES // 3) + "1]\n")
    with pytest.raises(InputError, match=r"big\.yaml: larger than 1 MiB"):
        load_yaml_file(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("a: &x [1, 2]\nb: [*x, *x]\n", r"^s: line 2, column 5: alias \*x; allowed: plain values"),
        ("a: &x [*x]\n", r"^s: line 1, column 8: alias \*x"),
        ("[" * 100 + "]" * 100, r"^s: line 1, column 33: nested too deeply; allowed: at most 32 levels"),
        ("kind: a\nname: b\nkind: c\n", r"^s: line 3, column 1: duplicate key 'kind' \(first at line 1\)"),
        ("{a: 1, a: 2}", r"^s: line 1, column 8: duplicate key 'a'"),
        ("{1: a, 0x1: b}", r"duplicate key 1 "),
        ("date: 2026-02-30\n", r"^s: unreadable YAML value \(day is out of range for month\)$"),
        ("n: " + "9" * 5000, r"^s: unreadable YAML value \(Exceeds the limit \(4300 digits\)"),
        ('name: "a\\ud800"', r"^s: name: text containing '\\ud800'; allowed: printable UTF-8 text"),
        ('"a\\x00b": 1', r"^s: top level: a key containing '\\x00'"),
        ("a: [1, {b: x\\x07}]", None),
    ],
)
def test_yaml_bounds(text, message):
    if message is None:
        assert parse_yaml(text, "s") == {"a": [1, {"b": "x\\x07"}]}  # a plain scalar keeps its backslash
        return
    with pytest.raises(InputError, match=message):
        parse_yaml(text, "s")


def test_anchors_without_aliases_and_nesting_up_to_the_bound_are_fine():
    assert parse_yaml("a: &x 1\nb: 2\n", "s") == {"a": 1, "b": 2}
    assert parse_yaml("[" * MAX_NESTING + "]" * MAX_NESTING, "s") is not None


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"a": 1, "a": 2}', r"^j: duplicate key 'a'; allowed: each key once$"),
        ("[NaN]", r"^j: NaN is not a JSON number; allowed: finite numbers, or null$"),
        ("[-Infinity]", r"^j: -Infinity is not a JSON number"),
        ("[" * 100_000 + "]" * 100_000, r"^j: nested too deeply; allowed: at most 32 levels"),
        ("[" * 40 + "]" * 40, r"^j: \[0\]\[0\].*: nested too deeply"),
        ('{"a": "\\ud800"}', r"^j: a: text containing '\\ud800'"),
        ("9" * 5000, r"^j: unreadable JSON value \(Exceeds the limit \(4300 digits\)"),
        ('{"a": ', r"^j: malformed JSON at line 1, column 7: Expecting value$"),
    ],
)
def test_json_bounds(text, message):
    with pytest.raises(InputError, match=message):
        parse_json(text, "j")


def test_json_may_allow_nan():
    value = parse_json("[NaN, 1]", "j", allow_nan=True)
    assert value[0] != value[0] and value[1] == 1


def test_one_out_dir_rule(tmp_path):
    from rig.inputs.files import check_out_dir

    blocker = tmp_path / "file"
    blocker.write_text("")
    check_out_dir(tmp_path)  # an existing writable directory
    check_out_dir(tmp_path / "new" / "deeper")  # one that can be made
    for out, message in [
        (blocker, f"--out {blocker}: not a directory; allowed"),
        (blocker / "sub", f"--out {blocker / 'sub'}: {blocker} is not a directory; allowed"),
    ]:
        with pytest.raises(InputError) as excinfo:
            check_out_dir(out)
        assert str(excinfo.value).startswith(message)
    with pytest.raises(InputError, match="no such directory; nothing to resume there"):
        check_out_dir(tmp_path / "missing", must_exist=True)


@pytest.fixture
def umask():
    """Set the process's umask for one test; the old one is restored after it."""
    old = os.umask(0o022)
    yield os.umask
    os.umask(old)


@pytest.mark.parametrize(("mask", "mode"), [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_an_atomic_write_gives_a_new_file_the_mode_open_would(tmp_path, umask, mask, mode):
    umask(mask)
    path = tmp_path / "journal.json"
    atomic_write_text(path, "{}\n")
    assert stat.S_IMODE(path.stat().st_mode) == mode
    assert [p.name for p in tmp_path.iterdir()] == ["journal.json"]


def test_an_atomic_rewrite_keeps_the_files_mode(tmp_path, umask):
    umask(0o077)
    path = tmp_path / "rig.yaml"
    path.write_text("name: a\n")
    path.chmod(0o664)  # shared with the lab's group
    atomic_write_text(path, "name: b\n")
    assert stat.S_IMODE(path.stat().st_mode) == 0o664
    assert path.read_text() == "name: b\n"


def test_a_calibration_is_written_as_the_umask_says(tmp_path, umask):
    umask(0o002)
    path = tmp_path / "cal.json"
    Calibration(1 / 80000, 120000, None, 9.80665, "2026-11-23", "test", "rig-lc1").save(path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o664


def test_a_run_lock_is_made_as_the_umask_says(tmp_path, umask):
    umask(0o002)  # a second account of the lab's group must be able to open it to resume the run
    lock = RunLock.acquire(tmp_path / "r.lock", "r")
    try:
        assert stat.S_IMODE((tmp_path / "r.lock").stat().st_mode) == 0o664
    finally:
        lock.release()
