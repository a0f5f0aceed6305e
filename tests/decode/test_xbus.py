"""Xsens Xbus framing and MTData2 decoding (decode/xbus.py) and the simulator's encoder (sim/xbus_encode.py), against
real MTi captures and the reference decoder's output for them (tests/data/xsens-mti: einride/xsens-go's test data,
Float32, FP12.20 and FP16.32): every packet decoded equal to the golden values, the same records however the bytes
are split into reads, noise and damaged messages skipped and counted with the rest decoded, and nothing raises."""

from __future__ import annotations

import math
import struct
from functools import cache
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slipdaq.decode.xbus import (
    FLOAT32,
    FLOAT64,
    FP1220,
    FP1632,
    ITEMS,
    MAX_NOISE_BYTES,
    MAX_PAYLOAD_BYTES,
    MID_MTDATA2,
    TYPE_MASK,
    GnssPvt,
    MtiPacket,
    UtcTime,
    XbusBytes,
    XbusDecoder,
    XbusFramer,
    decode_mtdata2,
    forward_accel_mps2,
    parse_message,
    xbus_message,
    xdi_name,
)
from slipdaq.sim.xbus_encode import encode_item, encode_packet, mti_message, utc_time
from support.paths import DATA

MTI = DATA / "xsens-mti"
CAPTURES = ("1", "2", "3")
"""Float32 with a StatusWord; FP12.20 and FP16.32 with a StatusByte."""
FUZZ = settings(max_examples=300, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@cache
def capture(name: str) -> bytes:
    return (MTI / name / "output.bin").read_bytes()


@cache
def messages(name: str) -> list[bytes]:
    return [bytes.fromhex(line) for line in (MTI / name / "messages.golden").read_text().split()]


def golden(name: str) -> list[list[tuple[str, list[str]]]]:
    """output.golden: per message, its items as (name as xsens-go prints it, the item's value lines)."""
    blocks = []
    for block in (MTI / name / "output.golden").read_text().split("\n\n"):
        items: list[tuple[str, list[str]]] = []
        for line in block.splitlines():
            if line.startswith("  "):
                items[-1][1].append(line[2:])
            else:
                items.append((line.removesuffix(":"), []))
        if items:
            blocks.append(items)
    return blocks


def rfc3339_epoch_ns(text: str) -> int:
    """Go's RFC 3339 with nanoseconds (`2019-01-20T13:47:24.1219Z`) -> nanoseconds since the Unix epoch."""
    import datetime as dt

    whole, _, fraction = text.removesuffix("Z").partition(".")
    t = dt.datetime.fromisoformat(whole).replace(tzinfo=dt.UTC)
    return int(t.timestamp()) * 1_000_000_000 + int(fraction.ljust(9, "0"))


LABELS = {1: [""], 2: ["Lat", "Lon"], 3: ["X", "Y", "Z"], 4: ["Q0", "Q1", "Q2", "Q3"]}
PVT_NAMES = ["ITOW", "Year", "Month", "Day", "Hour", "Min", "Sec", "Valid", "TAcc", "Nano", "FixType", "Flags", "NumSV",
             "Reserved1", "Lon", "Lat", "Height", "HMSL", "HAcc", "VAcc", "VelN", "VelE", "VelD", "GSpeed", "HeadMot",
             "SAcc", "HeadAcc", "HeadVeh", "GDOP", "PDOP", "TDOP", "VDOP", "HDOP", "NDOP", "EDOP"]


def assert_item_equals_golden(packet: MtiPacket, xdi: int, lines: list[str]) -> None:
    """One decoded item equal to xsens-go's text of it (floats exactly: the golden is Go's shortest round trip)."""
    item = ITEMS[xdi & TYPE_MASK]
    value = getattr(packet, item.attr)
    if item.floats:
        values = (value,) if item.floats == 1 else value
        pairs = [line.partition(":") if ":" in line else ("", "", line) for line in lines]
        assert [k for k, _, _ in pairs] == LABELS[item.floats]
        assert values == tuple(float(v) for _, _, v in pairs)
    elif item.name == "UTCTime":
        assert value.epoch_ns() == rfc3339_epoch_ns(lines[0])
        assert packet.utc_time_s == value.epoch_ns() / 1_000_000_000  # correctly rounded
    elif item.name in ("StatusWord", "StatusByte"):
        assert len(lines[0]) == (32 if item.name == "StatusWord" else 8) and value == int(lines[0], 2)
    elif item.name == "GNSSPVTData":
        assert [line.partition(":")[0] for line in lines] == PVT_NAMES
        assert value == GnssPvt(*(int(line.partition(":")[2]) for line in lines))
    else:
        assert value == int(lines[0])


def frame(data: bytes, cuts: list[int] | None = None) -> tuple[list[XbusBytes], XbusFramer]:
    """The records of a stream fed whole, or in reads cut at `cuts` (read i stamped i), then flushed."""
    framer = XbusFramer()
    bounds = sorted({0, len(data), *(c for c in cuts or [] if 0 <= c <= len(data))})
    records = [r for i, (a, b) in enumerate(zip(bounds, bounds[1:])) for r in framer.feed(data[a:b], float(i))]
    return records + framer.flush(), framer


def packets(records: list[XbusBytes]) -> list[MtiPacket]:
    decoder = XbusDecoder()
    return [p for r in records if (p := decoder.decode(r)) is not None]


@pytest.mark.parametrize("name", CAPTURES)
def test_every_packet_decodes_equal_to_the_reference_decoder(name: str) -> None:
    records, framer = frame(capture(name))
    assert [r.data for r in records] == messages(name)  # every byte framed: 100 messages, no noise
    assert (framer.messages, framer.bad_frames, framer.noise_bytes) == (100, 0, 0)
    decoded, expected = packets(records), golden(name)
    assert len(decoded) == len(expected) == 100
    for packet, items in zip(decoded, expected):
        assert [xdi_name(x) for x in packet.identifiers] == [header for header, _ in items]
        assert (packet.unknown_items, packet.bad_items) == (0, 0)
        for xdi, (_, lines) in zip(packet.identifiers, items):
            assert_item_equals_golden(packet, xdi, lines)
        assert packet.orientation_frame in (None, "ENU") and packet.velocity_frame in (None, "ENU")
    assert sum(p.acceleration_mps2 is not None for p in decoded) == 96
    assert sum(p.gnss_pvt is not None for p in decoded) == 4
    first = decoded[0].packet_counter or 0
    assert [p.packet_counter for p in decoded] == list(range(first, first + 100))
    assert all(p.utc_time is not None and p.utc_time.flags == 0x37 and p.utc_time_s is not None for p in decoded)


@pytest.mark.parametrize("name", CAPTURES)
def test_encoding_a_decoded_packet_gives_back_the_real_message(name: str) -> None:
    assert [encode_packet(p) for p in packets(frame(capture(name))[0])] == messages(name)


@pytest.mark.parametrize("name", CAPTURES)
def test_forward_acceleration_by_axis_and_sign(name: str) -> None:
    packet = next(p for p in packets(frame(capture(name))[0]) if p.acceleration_mps2 is not None)
    x, y, z = packet.acceleration_mps2  # type: ignore[misc]
    assert forward_accel_mps2(packet, "x", 1) == x and forward_accel_mps2(packet, "y", -1) == -y
    assert forward_accel_mps2(packet, "z", 1) == z
    assert forward_accel_mps2(MtiPacket(0.0, packet_counter=1), "x", 1) is None
    with pytest.raises(ValueError):
        forward_accel_mps2(packet, "x", 0)


@FUZZ
@given(st.sampled_from(CAPTURES), st.lists(st.integers(min_value=0, max_value=18_000), max_size=40))
def test_records_do_not_depend_on_reads(name: str, cuts: list[int]) -> None:
    data = capture(name)
    records, framer = frame(data, cuts)
    assert [r.data for r in records] == messages(name) and framer.pending_bytes == 0


def test_a_record_takes_the_time_of_its_last_byte() -> None:
    one, two = messages("1")[:2]
    framer = XbusFramer()
    assert framer.feed(one[:10], 1.0) == [] and framer.pending_bytes == 10
    assert [(r.timestamp_s, r.data) for r in framer.feed(one[10:] + b"\x00\x01", 2.0)] == [(2.0, one)]
    assert framer.feed(two[:5], 3.0) == [] and framer.pending_bytes == 7  # the noise is held until a message ends it
    out = framer.feed(two[5:], 4.0)
    assert [(r.timestamp_s, r.data) for r in out] == [(2.0, b"\x00\x01"), (4.0, two)]
    assert framer.pending_bytes == 0 and framer.flush() == []


GARBAGE = bytes(range(0x30, 0x90)) + b"\xfa\x00\xfa\xfa\xff\x36\x05\x01\x02" + b"\xfa\xff\x36\xff\x09\x00"
"""Noise with lone preambles, a header whose checksum fails and one whose extended length is beyond the limit."""


@pytest.mark.parametrize("name", CAPTURES)
def test_garbage_and_a_flipped_byte_are_skipped_and_counted(name: str) -> None:
    msgs = messages(name)
    damaged = bytearray(msgs[40])
    damaged[30] ^= 0x10
    stream = b"".join(msgs[:10]) + GARBAGE + b"".join(msgs[10:40]) + bytes(damaged) + b"".join(msgs[41:]) + b"\x00"
    for cuts in (None, list(range(0, len(stream), 7)), list(range(0, len(stream), 1000))):
        records, framer = frame(stream, cuts)
        assert b"".join(r.data for r in records) == stream  # lossless
        assert [r.data for r in records if parse_message(r.data)] == msgs[:40] + msgs[41:]
        assert all(len(r.data) <= MAX_NOISE_BYTES for r in records if not parse_message(r.data))
        assert framer.bad_frames >= 3 and framer.noise_bytes == len(GARBAGE) + len(damaged) + 1
        decoder = XbusDecoder()
        decoded = [p for r in records if (p := decoder.decode(r)) is not None]
        every = packets(frame(capture(name))[0])
        assert [p.packet_counter for p in decoded] == [p.packet_counter for i, p in enumerate(every) if i != 40]
        assert decoder.packets == 99 and decoder.noise_records == 3


@pytest.mark.parametrize("name", CAPTURES)
def test_truncated_input_never_raises(name: str) -> None:
    msgs = messages(name)
    data = b"".join(msgs[:3])
    for end in range(len(data) + 1):
        records, _ = frame(data[:end], [end // 2])
        assert b"".join(r.data for r in records) == data[:end]
        whole = [r.data for r in records if parse_message(r.data)]
        assert whole == [m for i, m in enumerate(msgs[:3]) if sum(map(len, msgs[: i + 1])) <= end]
        packets(records)
    for cut in range(len(msgs[0]) - 1):  # an MTData2 payload cut short (with a checksum that holds) decodes partly
        payload = parse_message(msgs[0])[1][:cut]  # type: ignore[index]
        packet = XbusDecoder().decode(XbusBytes(0.0, xbus_message(MID_MTDATA2, payload)))
        assert packet is not None and packet.bad_items <= 1


def test_utc_time_is_used_only_when_its_flags_say_valid() -> None:
    base = utc_time(1_548_000_000.25)
    assert base.epoch_ns() == 1_548_000_000_250_000_000
    for flags, valid in ((0x37, True), (0x07, True), (0x03, False), (0x04, False), (0x00, False)):
        u = UtcTime(base.nanosecond, base.year, base.month, base.day, base.hour, base.minute, base.second, flags)
        packet = decode_mtdata2(encode_item(0x1010, u))
        assert packet.utc_time == u and (packet.utc_time_s == 1_548_000_000.25) is valid
        assert valid or packet.utc_time_s is None
    for bad in (UtcTime(0, 2019, 13, 1, 0, 0, 0, 7), UtcTime(0, 2019, 2, 30, 0, 0, 0, 7), UtcTime(10**9, 2019, 1, 1, 0, 0, 0, 7),
                UtcTime(0, 2019, 1, 1, 24, 0, 0, 7), UtcTime(0, 0, 0, 0, 0, 0, 0, 7)):
        assert decode_mtdata2(encode_item(0x1010, bad)).utc_time_s is None


def test_all_number_formats_and_coordinate_systems() -> None:
    values = (1.5, -2.25, 1000.0078125)
    for precision in (FLOAT32, FP1220, FP1632, FLOAT64):
        payload = encode_item(0x4020 | precision, values) + encode_item(0x2034 | precision, values) \
            + encode_item(0xD018 | precision, values) + encode_item(0x5020 | precision, 12.5)
        packet = decode_mtdata2(payload)
        assert packet.acceleration_mps2 == packet.euler_angles_deg == packet.velocity_mps == values
        assert (packet.orientation_frame, packet.velocity_frame, packet.altitude_ellipsoid_m) == ("NED", "NWU", 12.5)
    assert decode_mtdata2(encode_item(0x4023, (0.1, 0.2, 0.3))).acceleration_mps2 == (0.1, 0.2, 0.3)  # Float64 exact
    fp1632 = decode_mtdata2(encode_item(0x4022, (-1.0 / 3, 32767.5, -32768.0))).acceleration_mps2
    assert fp1632 == (round(-2**32 / 3) / 2**32, 32767.5, -32768.0)
    assert xdi_name(0x2034) == "EulerAngles(NorthEastDown,Float32)" and xdi_name(0x4023) == "Acceleration(Float64)"


def test_unknown_and_malformed_items_are_skipped_by_their_size() -> None:
    accel = encode_item(0x4020, (1.0, 2.0, 3.0))
    unknown = b"\x0f\x10\x03abc"  # no such data type
    wrong_size = b"\x10\x20\x03\x00\x01\x02"  # PacketCounter is two bytes
    packet = decode_mtdata2(unknown + wrong_size + accel + encode_item(0x1020, 7))
    assert (packet.acceleration_mps2, packet.packet_counter) == ((1.0, 2.0, 3.0), 7)
    assert (packet.unknown_items, packet.bad_items, packet.identifiers) == (1, 1, (0x0F10, 0x1020, 0x4020, 0x1020))
    cut = decode_mtdata2(accel + b"\x10\x20\x02\x00")  # the last item runs past the payload
    assert (cut.acceleration_mps2, cut.bad_items) == ((1.0, 2.0, 3.0), 1)


def test_extended_length_and_other_messages() -> None:
    items = b"".join(encode_item(0x4020, (float(i), 0.0, 0.0)) for i in range(20))  # 300 bytes: an extended length
    big = xbus_message(MID_MTDATA2, items)
    assert big[3] == 0xFF and int.from_bytes(big[4:6], "big") == 300
    ack, error = xbus_message(0x31, b""), xbus_message(0x42, b"\x04")
    assert ack == bytes.fromhex("faff3100d0")  # GoToConfigAck as xsens-go's client test writes it
    too_long = b"\xfa\xff\x36\xff" + (MAX_PAYLOAD_BYTES + 1).to_bytes(2, "big") + bytes(MAX_PAYLOAD_BYTES + 2)
    stream = ack + big + too_long + error + messages("1")[0]
    records, framer = frame(stream, [3, 100, 400])
    decoder = XbusDecoder()
    decoded = [p for r in records if (p := decoder.decode(r)) is not None]
    assert [r.data for r in records if parse_message(r.data)] == [ack, big, error, messages("1")[0]]
    assert decoded[0].acceleration_mps2 == (19.0, 0.0, 0.0) and decoder.packets == 2
    assert (decoder.other_messages, decoder.error_messages, framer.bad_frames) == (2, 1, 1)
    with pytest.raises(ValueError):
        xbus_message(MID_MTDATA2, bytes(MAX_PAYLOAD_BYTES + 1))


def test_the_simulators_message_has_the_real_layout() -> None:
    """mti_message for a real Float32 packet's values: the real message's PacketCounter, SampleTimeFine, UTCTime and
    Acceleration items, in their order, framed and checksummed as the MTi frames them."""
    for raw, packet in zip(messages("1"), packets(frame(capture("1"))[0])):
        if packet.acceleration_mps2 is None:
            continue
        payload, pos, kept = parse_message(raw)[1], 0, b""  # type: ignore[index]
        while pos < len(payload):
            size = payload[pos + 2]
            if int.from_bytes(payload[pos : pos + 2], "big") in (0x1020, 0x1060, 0x1010, 0x4020):
                kept += payload[pos : pos + 3 + size]
            pos += 3 + size
        built = mti_message(packet.packet_counter, packet.sample_time_fine, packet.acceleration_mps2,  # type: ignore[arg-type]
                            utc=packet.utc_time)
        assert built == xbus_message(MID_MTDATA2, kept)


@FUZZ
@given(st.integers(min_value=0, max_value=2**40), st.integers(min_value=0, max_value=2**40),
       st.tuples(*[st.floats(min_value=-160.0, max_value=160.0)] * 3),
       st.one_of(st.none(), st.floats(min_value=0.0, max_value=4.1e9)), st.sampled_from((FLOAT32, FP1220, FP1632, FLOAT64)))
def test_encode_decode_round_trip(counter: int, ticks: int, accel: tuple[float, float, float], utc_s: float | None,
                                  precision: int) -> None:
    message = mti_message(counter, ticks, accel, utc=utc_s, free_acceleration_mps2=accel, precision=precision)
    records, _ = frame(message)
    assert [r.data for r in records] == [message]
    packet = packets(records)[0]
    assert (packet.packet_counter, packet.sample_time_fine) == (counter % 2**16, ticks % 2**32)
    if precision == FLOAT32:
        expected = struct.unpack(">3f", struct.pack(">3f", *accel))
    elif precision == FLOAT64:
        expected = accel
    else:
        scale = 2.0**20 if precision == FP1220 else 2.0**32
        expected = tuple(round(v * scale) / scale for v in accel)
    assert packet.acceleration_mps2 == packet.free_acceleration_mps2 == expected
    assert forward_accel_mps2(packet, "y", -1) == -expected[1]
    if utc_s is None:
        assert packet.utc_time is None and packet.utc_time_s is None
    else:
        assert packet.utc_time_s is not None and math.isclose(packet.utc_time_s, utc_s, abs_tol=1e-6)


PIECES = st.sampled_from([*messages("1")[:3], messages("3")[1], b"\xfa", b"\xfa\xff", b"\xfa\xff\x36", b"\xfa\xff\x36\xff",
                          b"\xfa\xff\x36\xff\x08\x00", xbus_message(0x31, b""), messages("2")[5][:40]])


@FUZZ
@given(st.lists(st.one_of(st.binary(max_size=300), PIECES), max_size=25), st.lists(st.integers(0, 4000), max_size=20))
def test_random_bytes_never_raise(parts: list[bytes], cuts: list[int]) -> None:
    data = b"".join(parts)
    records, framer = frame(data, cuts)
    assert b"".join(r.data for r in records) == data and framer.pending_bytes == 0
    assert [r.data for r in records] == [r.data for r in frame(data)[0]]
    noise = [r for r in records if parse_message(r.data) is None]
    assert all(0 < len(r.data) <= MAX_NOISE_BYTES for r in noise)
    assert framer.noise_bytes == sum(len(r.data) for r in noise) and framer.messages == len(records) - len(noise)
    for p in packets(records):
        assert p.bad_items >= 0
    decode_mtdata2(data[:MAX_PAYLOAD_BYTES])


def test_the_test_data_is_as_its_readme_says() -> None:
    assert (MTI / "LICENSE").read_text().startswith("Copyright 2020 Einride AB")
    assert "cab43081c6079641d7196dcb298e6c5a9fd09689" in (MTI / "README.md").read_text()
    assert sorted(p.name for p in Path(MTI).iterdir() if p.is_dir()) == list(CAPTURES)
