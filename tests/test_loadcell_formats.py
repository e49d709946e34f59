"""Line formats: golden lines, round trips, and the decoder's resynchronisation and counters."""

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.errors import InputError
from rig.hw.loadcell.formats import (
    FORCE_UNITS_N,
    MAX_INFO_LINE_BYTES,
    ChecksumError,
    DeviceReading,
    IndicatorStCodec,
    LineDecoder,
    LineError,
    RigLc1Codec,
    ValueUnitCodec,
    get_codec,
    nmea_checksum,
    nmea_checksums,
)
from rig.vocabulary import LOADCELL_FORMAT_TRAITS, LoadCellFormatName

LC1 = RigLc1Codec()
IND = IndicatorStCodec()


def test_rig_lc1_golden_line_checksum_worked_by_hand():
    # body "LC,7,1000,-42": XOR of its bytes, step by step:
    # L 0x4C; ^C 0x43 -> 0x0F; ^, 0x2C -> 0x23; ^7 0x37 -> 0x14; ^, -> 0x38; ^1 0x31 -> 0x09;
    # ^0 0x30 -> 0x39; ^0 -> 0x09; ^0 -> 0x39; ^, -> 0x15; ^- 0x2D -> 0x38; ^4 0x34 -> 0x0C; ^2 0x32 -> 0x3E
    assert nmea_checksum(b"LC,7,1000,-42") == 0x3E
    assert LC1.encode(DeviceReading(raw=-42, seq=7, device_time_us=1000)) == b"$LC,7,1000,-42*3E\r\n"
    assert LC1.decode(b"$LC,7,1000,-42*3E\r") == (-42, 7, 1000, True, False, False, None, 0)
    assert LC1.decode(b"$LC,7,1000,-42*3e").raw == -42  # lower-case hex and a bare LF are accepted


def test_rig_lc1_wraps_seq_and_device_time_on_encode():
    line = LC1.encode(DeviceReading(raw=5, seq=65536 + 3, device_time_us=(1 << 32) + 9))
    assert line.startswith(b"$LC,3,9,5*")


@pytest.mark.parametrize(
    "line",
    [
        b"$LC,7,1000,-42*3F",  # wrong checksum
        b"$LC,7,1000,-43*3E",  # a flipped digit
    ],
)
def test_rig_lc1_checksum_failures(line):
    with pytest.raises(ChecksumError):
        LC1.decode(line)


@pytest.mark.parametrize(
    "line",
    [
        b"$LC,7,1000",  # truncated
        b"$LC,7,1000,-42",  # no checksum
        b"$LC,7,1000,4x2*3E",
        b"LC,7,1000,-42*3E",  # no $
        b"$LC,70000,1000,-42*" + b"%02X" % nmea_checksum(b"LC,70000,1000,-42"),  # seq > 65535
        b"$LC,7,4294967296,1*" + b"%02X" % nmea_checksum(b"LC,7,4294967296,1"),  # t_us >= 2**32
    ],
)
def test_rig_lc1_malformed_lines(line):
    with pytest.raises(LineError) as exc:
        LC1.decode(line)
    assert not isinstance(exc.value, ChecksumError)


@given(
    raw=st.integers(-(1 << 31), (1 << 31) - 1),
    seq=st.integers(0, 65535),
    t_us=st.integers(0, (1 << 32) - 1),
)
def test_rig_lc1_round_trip(raw, seq, t_us):
    line = LC1.encode(DeviceReading(raw, seq, t_us))
    assert len(line) <= LC1.max_line_bytes
    decoded = LC1.decode(line[:-1])
    assert (decoded.raw, decoded.seq, decoded.device_time_us) == (raw, seq, t_us)


def test_indicator_golden_lines():
    assert IND.encode(DeviceReading(123)) == b"ST,GS,+0001.23kg\r\n"
    assert IND.encode(DeviceReading(-5, stable=False, net=True)) == b"US,NT,-0000.05kg\r\n"
    assert IND.encode(DeviceReading(10**9)) == b"OL,GS,+9999.99kg\r\n"  # clamped and flagged
    d = IND.decode(b"ST,GS,+0001.23kg\r")
    assert (d.raw, d.seq, d.device_time_us, d.stable, d.overload, d.net, d.unit, d.decimals) == (
        123,
        None,
        None,
        True,
        False,
        False,
        "kg",
        2,
    )
    d = IND.decode(b"OL,NT,-  12.5 lb")
    assert (d.raw, d.overload, d.net, d.unit, d.decimals) == (-125, True, True, "lb", 1)
    assert IndicatorStCodec(decimals=0, unit="N").encode(DeviceReading(42)) == b"ST,GS,+0000042N\r\n"


@pytest.mark.parametrize(
    "line", [b"ST,GS,+0001.23", b"XX,GS,+0001.23kg", b"ST,GS,+00.1.23kg", b"ST,GS,+   .   kg"]
)
def test_indicator_malformed(line):
    with pytest.raises(LineError):
        IND.decode(line)


@given(raw=st.integers(-999999, 999999), stable=st.booleans(), net=st.booleans())
def test_indicator_round_trip(raw, stable, net):
    decoded = IND.decode(IND.encode(DeviceReading(raw, stable=stable, net=net))[:-1])
    assert (decoded.raw, decoded.stable, decoded.net, decoded.decimals, decoded.unit) == (
        raw,
        stable,
        net,
        2,
        "kg",
    )


@pytest.mark.parametrize("name", list(LoadCellFormatName))
def test_every_format_has_a_codec_that_round_trips_and_keeps_its_bounds(name):
    # docs/extending.md: a new LoadCellFormatName fails here until its codec exists and is sound.
    codec = get_codec(name)
    assert codec.name == name
    for raw, seq in [(0, 0), (123, 7), (-5, 65535), (99999, 1)]:
        line = codec.encode(DeviceReading(raw, seq, 1000))
        assert line.endswith(b"\n") and len(line) <= codec.max_line_bytes
        assert codec.count_line_starts(line) == 1 and codec.last_line_start(line) == 0
        decoded = codec.decode(line[:-1])
        if isinstance(codec, ValueUnitCodec):  # a display: raw (micronewtons) to its last digit
            step_un = 10.0**-codec.decimals * FORCE_UNITS_N[codec.unit] * 1e6
            assert abs(decoded.raw - raw) <= step_un / 2 + 1
            assert codec.encode(DeviceReading(decoded.raw)) == line
        else:
            assert decoded.raw == raw
        assert decoded.seq == (seq if codec.has_sequence else None)
    assert LOADCELL_FORMAT_TRAITS[name].max_line_bytes == codec.max_line_bytes


@pytest.mark.parametrize(
    ("line", "newtons"),
    [
        # Mark-10 Series 4 user's guide, 9.1.4: tension and compression replies.
        (b"-18.78 lbF", -18.78 * 4.4482216152605),
        (b"4.285 N", 4.285),
        (b"12.5 ozF", 12.5 * 0.27801385095378125),
        (b"+1.250 kgf", 1.25 * 9.80665),
        (b"500 gF", 500 * 0.00980665),
        (b"0.1234 kN", 123.4),
        (b"7N", 7.0),
    ],
)
def test_value_unit_lines_in_every_force_unit_are_read_in_newtons(line, newtons):
    decoded = ValueUnitCodec().decode(line + b"\r")
    assert decoded.raw == round(newtons * 1e6) and decoded.unit == "N" and decoded.seq is None


@pytest.mark.parametrize("line", [b"-18.78", b"18.78 kg", b"1.2.3 N", b"- 5 N", b"N", b"12 lbF extra"])
def test_value_unit_refuses_lines_without_a_force_unit(line):
    with pytest.raises(LineError):
        ValueUnitCodec().decode(line)


def test_value_unit_decoder_resyncs_after_garbage():
    decoder = LineDecoder(ValueUnitCodec())
    lines = decoder.feed(b"\x81\x82-18.78 lbF\r\n*10\r\n4.285 N\r\n")
    assert [ln.raw for ln in lines] == [round(-18.78 * 4.4482216152605e6), 4_285_000]


def test_registry_rejects_unknown_format():
    assert get_codec("rig-lc1").name == "rig-lc1"
    with pytest.raises(InputError, match="allowed: indicator-st, rig-lc1"):
        get_codec("nmea")


def lc1_lines(n, start_seq=0):
    return [LC1.encode(DeviceReading(1000 + k, (start_seq + k) % 65536, 1000 * k)) for k in range(n)]


def test_decoder_resyncs_after_garbage_without_counting_a_corrupt_line():
    lines = lc1_lines(3)
    garbage = b"\x00\xff\x13 noise"
    decoder = LineDecoder(LC1)
    out = decoder.feed(lines[0] + garbage + lines[1] + lines[2])
    assert [d.seq for d in out] == [0, 1, 2]
    c = decoder.counts()
    assert (c.lines_ok, c.corrupt_lines, c.checksum_failures, c.bytes_discarded) == (3, 0, 0, len(garbage))


def test_decoder_counts_truncated_line_glued_to_the_next():
    lines = lc1_lines(3)
    stream = lines[0] + lines[1][:9] + lines[2]  # line 1 lost its tail and terminator
    decoder = LineDecoder(LC1)
    out = decoder.feed(stream)
    assert [d.seq for d in out] == [0, 2]
    c = decoder.counts()
    assert (c.corrupt_lines, c.bytes_discarded, c.sequence_gaps, c.missing_samples) == (1, 9, 1, 1)


def test_decoder_counts_checksum_failure_and_terminated_short_line():
    lines = lc1_lines(4)
    bad = lines[1].replace(lines[1][-4:-2], b"00" if lines[1][-4:-2] != b"00" else b"01")
    decoder = LineDecoder(LC1)
    out = decoder.feed(lines[0] + bad + b"$LC,2,20\r\n" + lines[3])
    assert [d.seq for d in out] == [0, 3]
    c = decoder.counts()
    assert (c.checksum_failures, c.corrupt_lines, c.missing_samples, c.sequence_gaps) == (1, 1, 2, 1)
    assert c.bytes_discarded == len(bad) + len(b"$LC,2,20\r\n")


def test_decoder_sequence_gap_across_16_bit_wrap():
    lines = lc1_lines(6, start_seq=65533)  # 65533, 65534, 65535, 0, 1, 2
    decoder = LineDecoder(LC1)
    out = decoder.feed(lines[0] + lines[1] + lines[4] + lines[5])  # 65535 and 0 missing
    assert [d.seq for d in out] == [65533, 65534, 1, 2]
    c = decoder.counts()
    assert (c.sequence_gaps, c.missing_samples) == (1, 2)
    decoder2 = LineDecoder(LC1)
    decoder2.feed(b"".join(lines))
    assert decoder2.counts().missing_samples == 0  # a plain wrap is not a gap


def test_decoder_handles_lines_split_at_every_byte():
    stream = b"".join(lc1_lines(5))
    decoder = LineDecoder(LC1)
    out = []
    for i in range(len(stream)):
        out += decoder.feed(stream[i : i + 1])
    assert [d.raw for d in out] == [1000, 1001, 1002, 1003, 1004]
    assert decoder.pending_bytes == 0 and decoder.counts().bytes_discarded == 0


def test_decoder_drops_overlong_unterminated_garbage_but_keeps_a_following_line_start():
    decoder = LineDecoder(LC1)
    assert decoder.feed(b"x" * 500) == []
    assert decoder.pending_bytes <= decoder.max_line_bytes
    line = lc1_lines(1)[0]
    assert [d.raw for d in decoder.feed(b"y" * 100 + line)] == [1000]
    c = decoder.counts()
    assert c.bytes_discarded == 600 and c.corrupt_lines == 0


def test_indicator_decoder_resyncs_and_counts_truncated_line():
    a, b = IND.encode(DeviceReading(100)), IND.encode(DeviceReading(-250, stable=False))
    decoder = LineDecoder(IND)
    out = decoder.feed(b"\x01\x02" + a + a[:9] + b + b"OL,GS,+9999.99kg\r\n")
    assert [(d.raw, d.stable, d.overload) for d in out] == [
        (100, True, False),
        (-250, False, False),
        (999999, False, True),
    ]
    c = decoder.counts()
    assert (c.corrupt_lines, c.bytes_discarded, c.overload_lines, c.sequence_gaps) == (1, 2 + 9, 1, 0)


@given(st.lists(st.one_of(st.sampled_from(lc1_lines(4)), st.binary(max_size=40)), max_size=30), st.data())
def test_decoder_accounts_for_every_byte(chunks, data):
    stream = b"".join(chunks)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    decoder = LineDecoder(LC1)
    out = []
    for lo, hi in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += decoder.feed(stream[lo:hi])
    ok_bytes = sum(len(LC1.encode(DeviceReading(d.raw, d.seq, d.device_time_us))) for d in out)
    info = decoder.take_info()  # random bytes may hold an information line, e.g. b"#\n"
    c = decoder.counts()
    assert c.bytes_received == len(stream)
    # Every valid line is counted with CRLF; a line received with a bare LF would be one byte shorter.
    info_bytes = sum(i.line_bytes for i in info)
    assert c.bytes_received == ok_bytes + info_bytes + c.bytes_discarded + decoder.pending_bytes
    assert c.lines_ok == len(out)
    assert c.info_lines == len(info)


@pytest.mark.parametrize("count", [1, 7, 8, 50])
def test_nmea_checksums_equal_nmea_checksum_of_each_body(count):
    rng = random.Random(count)
    bodies = [bytes(rng.randrange(256) for _ in range(rng.randrange(33))) for _ in range(count)]
    assert nmea_checksums(bodies) == [nmea_checksum(body) for body in bodies]


def feed_both(chunks):
    """The same chunks through `feed` (the plain decoder) and `feed_columns` (the fast path)."""
    by_line, by_block = LineDecoder(LC1), LineDecoder(LC1)
    for chunk in chunks:
        lines = by_line.feed(chunk)
        columns = by_block.feed_columns(chunk)
        assert columns == ([d.raw for d in lines], [d.seq for d in lines], [d.device_time_us for d in lines])
    assert by_block.counts() == by_line.counts()
    assert by_block.pending_bytes == by_line.pending_bytes
    return by_block


def test_feed_columns_equals_feed_on_valid_blocks_and_on_each_kind_of_damage():
    lines = [LC1.encode(DeviceReading(raw, seq, t)) for raw, seq, t in [(-5, 65535, 0), (7, 0, 2**32 - 1)]]
    lines += lc1_lines(20)
    block = b"".join(lines)
    assert feed_both([block]).counts().lines_ok == len(lines)
    assert feed_both([block.replace(b"\r\n", b"\n")]).counts().lines_ok == len(lines)  # bare LF
    lower_hex = b"".join(line[:-4] + line[-4:-2].lower() + b"\r\n" for line in lines)
    assert lower_hex != block and feed_both([lower_hex]).counts().lines_ok == len(lines)
    star = lines[3].index(b"*")
    bad_checksum = lines[3][: star + 1] + b"%02X" % (int(lines[3][star + 1 : star + 3], 16) ^ 1) + b"\r\n"
    seq_too_big = b"$LC,70000,1,1*%02X\r\n" % nmea_checksum(b"LC,70000,1,1")
    for broken in (b"x", b"\n", lines[4][:-2], bad_checksum, seq_too_big):
        counts = feed_both([b"".join(lines[:3]) + broken + b"".join(lines[4:])]).counts()
        assert counts.lines_ok < len(lines)
    assert feed_both([b"no lines\n"]).counts().bytes_discarded == 9


# Information lines: printable ASCII but "#" and "$".
INFO_ALPHABET = "".join(chr(c) for c in range(0x20, 0x7F) if chr(c) not in "#$")
BANNER = b"#BOOT fw=rig-hx711/1.0.0 adc=HX711 gain=A128 sps=80 period-us=12500\r\n"
INFO = st.builds(
    lambda text, crlf: b"#" + text.encode() + (b"\r\n" if crlf else b"\n"),
    st.one_of(st.just("BOOT fw=rig-hx711/1.0.0 adc=HX711"), st.text(INFO_ALPHABET, max_size=71)),
    st.booleans(),
)


def test_information_lines_are_counted_and_kept_never_damage_nor_samples():
    decoder = LineDecoder(LC1)
    stream = BANNER + b"#INFO dout=D8 sck=D9\n" + b"".join(lc1_lines(3)) + b"#WARN late\r\n"
    out = decoder.feed(stream)
    c = decoder.counts()
    assert [d.seq for d in out] == [0, 1, 2]
    assert (c.info_lines, c.restarts, c.bytes_discarded, c.corrupt_lines, c.sequence_gaps) == (3, 0, 0, 0, 0)
    info = decoder.take_info()
    assert [(i.text, i.banner, i.restart, i.sample_index) for i in info] == [
        (BANNER[1:-2].decode(), True, False, 0),
        ("INFO dout=D8 sck=D9", False, False, 0),
        ("WARN late", False, False, 3),
    ]
    assert sum(i.line_bytes for i in info) + sum(map(len, lc1_lines(3))) == len(stream)
    assert decoder.take_info() == []  # handed over once


def test_a_banner_after_a_sample_is_a_restart_not_a_sequence_gap():
    before, after = lc1_lines(5, start_seq=100), lc1_lines(4)
    restarted = LineDecoder(LC1)
    out = restarted.feed(b"".join(before) + BANNER + b"".join(after))
    assert [d.seq for d in out] == [100, 101, 102, 103, 104, 0, 1, 2, 3]
    c = restarted.counts()
    assert (c.restarts, c.sequence_gaps, c.missing_samples, c.info_lines) == (1, 0, 0, 1)
    assert [(i.restart, i.sample_index) for i in restarted.take_info()] == [(True, 5)]
    # Without the banner the same stream is a gap; and a banner split from its samples across
    # reads, or after a line the reset cut short, is the same restart.
    plain = LineDecoder(LC1)
    plain.feed(b"".join(before + after))
    assert (plain.counts().sequence_gaps, plain.counts().restarts) == (1, 0)
    split = LineDecoder(LC1)
    for chunk in (b"".join(before), BANNER[:20], BANNER[20:] + after[0], b"".join(after[1:])):
        split.feed(chunk)
    cut = LineDecoder(LC1)
    cut.feed(b"".join(before) + after[0][:9] + BANNER + b"".join(after))
    for decoder, corrupt in ((split, 0), (cut, 1)):
        c = decoder.counts()
        counted = (c.lines_ok, c.restarts, c.sequence_gaps, c.missing_samples, c.corrupt_lines)
        assert counted == (9, 1, 0, 0, corrupt)


def test_what_is_not_an_information_line_stays_garbage():
    too_long = b"#" + b"x" * (MAX_INFO_LINE_BYTES - 2) + b"\r\n"  # 75 bytes
    fits = b"#" + b"x" * (MAX_INFO_LINE_BYTES - 3) + b"\r\n"  # 74 bytes
    for bad in (b"#bell \x07\r\n", b"#dollar $ sign\n", b"#tab\there\n", too_long):
        decoder = LineDecoder(LC1)
        decoder.feed(bad + lc1_lines(1)[0])
        c = decoder.counts()
        assert (c.info_lines, c.lines_ok, c.bytes_discarded) == (0, 1, len(bad))
    decoder = LineDecoder(LC1)
    decoder.feed(fits)
    assert decoder.counts().info_lines == 1
    indicator = LineDecoder(IND)  # indicator-st has no information lines
    indicator.feed(BANNER)
    assert (indicator.counts().info_lines, indicator.counts().bytes_discarded) == (0, len(BANNER))


@settings(max_examples=300)
@given(
    st.lists(st.one_of(INFO, st.sampled_from(lc1_lines(10)), st.binary(max_size=20)), max_size=30),
    st.data(),
)
def test_information_lines_survive_damage_around_them(chunks, data):
    stream = b"".join(chunks)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    decoder = LineDecoder(LC1)
    for lo, hi in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        decoder.feed(stream[lo:hi])
    info = decoder.take_info()
    sent = [c[1:].rstrip(b"\r\n").decode() for c in chunks if c.startswith(b"#") and c.endswith(b"\n")]
    sent = [text for text in sent if all(ch in INFO_ALPHABET for ch in text) and len(text) <= 71]
    # Every information line arrives, whatever garbage (without a line end) was glued before it;
    # more can only come from random bytes that happen to form one.
    received = iter(i.text for i in info)
    assert all(text in received for text in sent)  # in order
    assert decoder.counts().info_lines == len(info) >= len(sent)


def garble(line, kind, rng):
    """A rig-lc1 line damaged as a serial link or a firmware bug might (`kind` 0-9): most are then invalid."""
    i = rng.randrange(len(line))
    if kind == 0:
        return line[:i] + line[i + 1 :]  # a byte lost
    if kind == 1:
        return line[:i] + bytes([line[i] ^ (1 << rng.randrange(8))]) + line[i + 1 :]  # a bit flipped
    if kind == 2:
        return line[:i] + bytes([rng.randrange(256)]) + line[i:]  # a byte inserted
    if kind == 3:
        return line[:i]  # truncated
    if kind == 4:
        return line[:-4] + line[-4:-2].lower() + b"\r\n"  # lower-case hex: still valid
    if kind == 5:
        return line.replace(b"\r\n", b"\n")  # bare LF: still valid
    # Well-formed with a correct checksum, but a field out of its range (a firmware bug).
    seq, t_us, raw = (int(field) for field in line[4 : line.index(b"*")].split(b","))
    big = rng.randrange(2**32, 10**10)  # at most 10 digits, as the format allows
    fields = [(seq % 34464 + 65536, t_us, raw), (seq, big, raw), (seq, t_us, big), (seq, t_us, -big)]
    body = b"LC,%d,%d,%d" % fields[kind - 6]
    return b"$%b*%02X\r\n" % (body, nmea_checksum(body))


VALID = st.one_of(
    INFO,
    st.sampled_from(lc1_lines(40)),
    st.builds(  # an unbroken run of sequence numbers, possibly across the wrap
        lambda n, start: b"".join(lc1_lines(n, start)), st.integers(1, 20), st.integers(65500, 65535)
    ),
)
DAMAGE = st.one_of(
    st.builds(garble, st.sampled_from(lc1_lines(40)), st.integers(0, 9), st.randoms(use_true_random=False)),
    st.binary(max_size=40),
    st.just(b"$"),
)


@settings(max_examples=800)  # the fast path is easy to get subtly wrong: look harder
@given(st.lists(VALID, max_size=40), st.lists(st.tuples(st.integers(0, 40), DAMAGE), max_size=4), st.data())
def test_feed_columns_equals_feed(valid, damage, data):
    chunks = list(valid)
    for at, bad in damage:
        chunks.insert(at, bad)
    stream = b"".join(chunks)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    feed_both([stream[lo:hi] for lo, hi in zip([0, *cuts], [*cuts, len(stream)], strict=True)])


def test_feed_columns_counts_gaps_and_wraps_like_feed():
    lines = [LC1.encode(DeviceReading(k, seq, 1000 * k)) for k, seq in enumerate([65534, 65535, 0, 1, 5, 6])]
    lines += lc1_lines(30)  # seq 0.. again: a gap back to 0
    by_block = feed_both([b"".join(part) for part in (lines[:2], lines[2:5], lines[5:])])
    assert by_block.counts().sequence_gaps == 2
