"""The firmware's pure parts (firmware/rig_hx711/lc1_line.c) compiled for the host and called through
ctypes: every line it formats must be the rig's own codec's line, byte for byte.

The same source file is compiled into the image; tests/test_firmware_simavr.py runs that image.
"""

from __future__ import annotations

import ctypes
import random
import shutil
import subprocess
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rig.hw.loadcell.formats import MAX_INFO_LINE_BYTES, DeviceReading, LineDecoder, RigLc1Codec

SOURCE = Path(__file__).resolve().parent.parent / "firmware" / "rig_hx711" / "lc1_line.c"
LC1 = RigLc1Codec()


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    if shutil.which("cc") is None:
        pytest.skip("no host C compiler (cc) to build firmware/rig_hx711/lc1_line.c")
    out = tmp_path_factory.mktemp("lc1") / "liblc1_line.so"
    subprocess.run(
        ["cc", "-O2", "-Wall", "-Wextra", "-Werror", "-shared", "-fPIC", "-o", str(out), str(SOURCE)],
        check=True,
    )
    lib = ctypes.CDLL(str(out))
    lib.lc1_format_sample.argtypes = [ctypes.c_char_p, ctypes.c_uint16, ctypes.c_uint32, ctypes.c_int32]
    lib.lc1_format_sample.restype = ctypes.c_uint8
    lib.lc1_format_info.argtypes = [ctypes.c_char_p, ctypes.c_char_p]
    lib.lc1_format_info.restype = ctypes.c_uint8
    lib.hx711_sign_extend.argtypes = [ctypes.c_uint32]
    lib.hx711_sign_extend.restype = ctypes.c_int32
    lib.capture_time_us.argtypes = [ctypes.c_uint32, ctypes.c_uint16, ctypes.c_uint8]
    lib.capture_time_us.restype = ctypes.c_uint32
    lib.rate_sps.argtypes = [ctypes.c_uint32]
    lib.rate_sps.restype = ctypes.c_uint16
    return lib


def sample_line(lib, seq: int, t_us: int, raw: int) -> bytes:
    buf = ctypes.create_string_buffer(64)
    n = lib.lc1_format_sample(buf, seq, t_us, raw)
    return buf.raw[:n]


def test_sample_lines_equal_the_codecs_at_the_edges(lib):
    for seq in (0, 9, 10, 65535):
        for t_us in (0, 1, 999_999, 2**32 - 1):
            for raw in (0, -1, 1, 0x7FFFFF, -0x800000, 2**31 - 1, -(2**31)):
                assert sample_line(lib, seq, t_us, raw) == LC1.encode(DeviceReading(raw, seq, t_us))
    longest = sample_line(lib, 65535, 2**32 - 1, -(2**31))
    assert len(longest) == LC1.max_line_bytes == 37  # LC1_MAX_LINE_BYTES, the firmware's buffer


@given(st.integers(0, 65535), st.integers(0, 2**32 - 1), st.integers(-(2**31), 2**31 - 1))
def test_sample_lines_equal_the_codecs(lib, seq, t_us, raw):
    assert sample_line(lib, seq, t_us, raw) == LC1.encode(DeviceReading(raw, seq, t_us))


def test_sign_extension_of_24_bit_codes(lib):
    cases = {
        0x000000: 0,
        0x000001: 1,
        0x7FFFFF: 8388607,
        0x800000: -8388608,
        0xFFFFFF: -1,
        0x800001: -8388607,
    }
    for code, count in cases.items():
        assert lib.hx711_sign_extend(code) == count
        assert lib.hx711_sign_extend(code | 0xAB000000) == count  # bits above 23 are ignored
    rng = random.Random(0)
    for code in (rng.randrange(1 << 24) for _ in range(1000)):
        assert lib.hx711_sign_extend(code) == code - (1 << 24 if code & 0x800000 else 0)


def test_capture_time_counts_an_overflow_pending_at_the_capture_only_when_it_came_first(lib):
    # 0.5 us ticks, 65536 per overflow (32768 us).
    assert lib.capture_time_us(0, 0, 0) == 0
    assert lib.capture_time_us(3, 200, 0) == 3 * 32768 + 100
    assert lib.capture_time_us(3, 200, 1) == 4 * 32768 + 100  # captured just after an unserviced wrap
    assert lib.capture_time_us(3, 65000, 1) == 3 * 32768 + 32500  # the wrap came after the capture
    # It wraps at 2**32 us, as t-us must: 2**17 overflows of 2**15 us.
    assert lib.capture_time_us(2**17, 2, 0) == 1
    assert lib.capture_time_us(2**17 - 1, 65534, 0) == 2**32 - 1


def test_rate_from_the_measured_period(lib):
    assert [lib.rate_sps(p) for p in (100_000, 50_000, 12_500, 3125, 96_154, 0)] == [10, 20, 80, 320, 10, 0]


@given(st.binary(max_size=120).filter(lambda b: b"\x00" not in b))
def test_information_lines_are_always_valid_whatever_the_text(lib, text):
    buf = ctypes.create_string_buffer(MAX_INFO_LINE_BYTES + 8)
    n = lib.lc1_format_info(buf, text)
    line = buf.raw[:n]
    assert n <= MAX_INFO_LINE_BYTES and line.startswith(b"#") and line.endswith(b"\r\n")
    decoder = LineDecoder(LC1)
    decoder.feed(line)
    assert decoder.counts().info_lines == 1 and decoder.counts().bytes_discarded == 0
    printable = bytes(b if 0x20 <= b <= 0x7E and b not in b"#$" else ord("?") for b in text)
    assert decoder.take_info()[0].text.encode() == printable[: MAX_INFO_LINE_BYTES - 3]
