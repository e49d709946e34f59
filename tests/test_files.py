import pytest

from rig.errors import InputError
from rig.files import load_yaml_file, read_text_file


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
        (_binary, r"bin\.csv: not UTF-8 text; allowed: a CSV file$"),
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
