"""Protocol s2r at the byte level: CRC, framing, resynchronisation, payload codecs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.errors import ProtocolError
from hardware.protocols import s2r
from hardware.protocols.s2r import S2RFramer, crc16, encode_frame


def _crc_reference(data: bytes) -> int:
    """Bit-by-bit CRC-16/CCITT-FALSE, written from the definition (poly 0x1021, init 0xFFFF)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def test_crc_check_value_and_reference() -> None:
    assert crc16(b"123456789") == 0x29B1  # the catalogued check value of CRC-16/CCITT-FALSE
    rng = np.random.default_rng(0)
    for n in (0, 1, 7, 64):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert crc16(data) == _crc_reference(data)


def test_frame_layout() -> None:
    f = encode_frame(0x2A, s2r.SET_TARGETS, b"\x01\x02\x03")
    assert f[:2] == b"\xa5\x5a"
    assert f[2] == 3 and f[3] == 0xFC  # LEN and ~LEN
    assert f[4] == 0x2A and f[5] == s2r.SET_TARGETS
    assert f[6:9] == b"\x01\x02\x03"
    assert int.from_bytes(f[9:11], "little") == _crc_reference(f[2:9])
    with pytest.raises(ValueError):
        encode_frame(0, s2r.PING, bytes(s2r.MAX_PAYLOAD + 1))


frames_st = st.lists(
    st.tuples(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=s2r.MAX_PAYLOAD)),
    min_size=1,
    max_size=6,
)


@settings(max_examples=150, deadline=None)
@given(
    frames=frames_st,
    garbage=st.lists(st.binary(max_size=20), min_size=7, max_size=7),
    cuts=st.lists(st.integers(0, 400), max_size=8),
)
def test_frames_survive_garbage_and_any_chunking(
    frames: list[tuple[int, int, bytes]], garbage: list[bytes], cuts: list[int]
) -> None:
    # garbage may not contain a sync pair followed by a valid frame by chance; strip sync bytes
    garbage = [g.replace(b"\xa5", b"\x00") for g in garbage]
    stream = garbage[0]
    for k, (seq, typ, payload) in enumerate(frames):
        stream += encode_frame(seq, typ, payload) + garbage[k + 1]
    framer = S2RFramer()
    got = []
    pos = 0
    for c in sorted(set(min(c, len(stream)) for c in cuts)) + [len(stream)]:
        got += framer.feed(stream[pos:c], 0.0)
        pos = c
    assert [(f.seq, f.type, f.payload) for f in got] == frames
    assert framer.stats.garbage_bytes == sum(len(g) for g in garbage[: len(frames) + 1])


@settings(max_examples=300, deadline=None)
@given(
    seq=st.integers(0, 255),
    payload=st.binary(max_size=24),
    where=st.integers(0, 10_000),
    flip=st.integers(1, 255),
)
def test_a_corrupted_byte_never_yields_a_frame(
    seq: int, payload: bytes, where: int, flip: int
) -> None:
    good = encode_frame(seq, s2r.SET_TARGETS, payload)
    bad = bytearray(good)
    bad[where % len(bad)] ^= flip
    framer = S2RFramer()
    follow = encode_frame((seq + 1) & 0xFF, s2r.PING)
    out = framer.feed(bytes(bad) + follow, 0.0)
    # the corrupted frame is rejected, the following good one is still found
    assert [(f.seq, f.type) for f in out] == [((seq + 1) & 0xFF, s2r.PING)]
    st_ = framer.stats
    assert st_.crc_errors + st_.header_errors + st_.garbage_bytes > 0


def test_partial_frame_is_abandoned_after_a_gap() -> None:
    framer = S2RFramer(gap_s=0.010)
    f1 = encode_frame(1, s2r.PING)
    assert framer.feed(f1[:5], 0.000) == []
    f2 = encode_frame(2, s2r.PING)
    out = framer.feed(f2, 0.050)
    assert [f.seq for f in out] == [2]
    assert framer.stats.gap_resets == 1 and framer.stats.garbage_bytes == 5


def test_payload_codecs_round_trip() -> None:
    pong = s2r.PongPayload(1, 1, 0, 4, 0xBEEF, 0x1234, 250)
    assert s2r.PongPayload.decode(pong.encode()) == pong
    state = s2r.StatePayload(0x05, 7, (1500, 1600, 1700, 1800), (1501, 1601, 1701, 1801), 0b1010)
    assert s2r.StatePayload.decode(state.encode(), 4) == state
    assert state.encode()[3] == 0b1010  # the readings byte follows flags and boot id
    assert state.measured_array().tolist() == [False, True, False, True]
    assert s2r.decode_targets(s2r.encode_targets([500, 2500, 1500])) == (500, 2500, 1500)
    lo, hi, step = (501, 900), (2499, 2000), (159, 100)
    assert s2r.decode_limits(s2r.encode_limits(lo, hi, step)) == (lo, hi, step)
    # a protocol-1 STATE (no readings byte) is refused, never misread
    with pytest.raises(
        ProtocolError, match=r"has 19 bytes, expected 20 for 4 actuators \(protocol 2\)"
    ):
        s2r.StatePayload.decode(b"\x00" * 19, 4)
    assert s2r.encode_torque(False, [1500, 1600]) == b"\x00"
    assert s2r.encode_torque(True) == b"\x01"
    assert s2r.encode_torque(True, [1500, 1600]) == b"\x01\xdc\x05\x40\x06"
    with pytest.raises(ProtocolError):
        s2r.PongPayload.decode(b"\x00")


def test_pong_keeps_its_layout_so_either_version_stops_in_one_line() -> None:
    """PONG did not change in protocol 2: a protocol-1 host decodes it, reads version 2 and
    stops with its own one-line version error (its check is the same code as below)."""
    pong = s2r.PongPayload(s2r.PROTO_VERSION, *s2r.FW_VERSION, 4, 1, 2, 250).encode()
    assert len(pong) == 10 and pong[0] == 2 == s2r.PROTO_VERSION


def test_a_protocol_1_device_is_refused_with_one_line() -> None:
    """A board still running protocol-1 firmware, over a real pty: connect stops at the PING."""
    import os
    import threading

    from hardware.serial_arm import SerialArm
    from hardware.spec import load_spec

    spec = load_spec()
    master, slave = os.openpty()
    stop = threading.Event()

    def device() -> None:  # answers every PING as protocol-1 firmware did
        framer = S2RFramer()
        while not stop.is_set():
            import select

            ready, _, _ = select.select([master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(master, 256)
            except OSError:
                return
            for f in framer.feed(data, 0.0):
                if f.type == s2r.PING:
                    old = s2r.PongPayload(1, 1, 0, 4, 7, 0, 250).encode()
                    os.write(master, encode_frame(f.seq, s2r.PING | s2r.REPLY, old))

    thread = threading.Thread(target=device, daemon=True)
    thread.start()
    try:
        arm = SerialArm(spec, os.ttyname(slave), protocol="s2r", timeout_s=0.2)
        with pytest.raises(ProtocolError) as info:
            arm.connect()
        msg = str(info.value)
        assert "\n" not in msg
        assert "firmware speaks s2r protocol version 1, this host speaks 2" in msg
    finally:
        stop.set()
        thread.join(timeout=2.0)
        os.close(master)
        os.close(slave)
