"""Passive J1939-21 transport protocol reassembly (BAM and RTS/CTS sessions seen on the bus)."""

from __future__ import annotations

from tractionecu.bus import j1939
from tractionecu.bus.candump import Frame
from tractionecu.bus.transport import PGN_TP_CM, PGN_TP_DT, Reassembler, with_reassembled


def cm(sa: int, da: int, ctrl: int, size: int, pgn: int) -> tuple[int, bytes]:
    packets = min((size + 6) // 7, 255)
    return (j1939.make_id(7, PGN_TP_CM, sa, da),
            bytes([ctrl, size & 0xFF, size >> 8, packets, 0xFF]) + pgn.to_bytes(3, "little"))


def dts(sa: int, da: int, payload: bytes) -> list[tuple[int, bytes]]:
    cid = j1939.make_id(7, PGN_TP_DT, sa, da)
    return [(cid, bytes([k + 1]) + payload[7 * k:7 * k + 7].ljust(7, b"\xff")) for k in range((len(payload) + 6) // 7)]


PAYLOAD = bytes(range(34))
EC1 = 65251


def feed_all(tp: Reassembler, frames) -> list:
    return [r for r in (tp.feed(c, d) for c, d in frames) if r is not None]


def test_bam_gives_the_message_after_its_last_packet():
    tp = Reassembler()
    frames = [cm(0x00, 0xFF, 32, 34, EC1), *dts(0x00, 0xFF, PAYLOAD)]
    out = [tp.feed(c, d) for c, d in frames]
    assert out[:-1] == [None] * 5 and out[-1] == (EC1, 0x00, PAYLOAD)


def test_the_jd5055e_ec1_bam():
    lines = ["1CECFF00#20220005FFE3FE00", "1CEBFF00#01201CDD6842DCA0", "1CEBFF00#020FD58D20E37A31",
             "1CEBFF00#03F1C044FFFF0401", "1CEBFF00#04204E0001FAC9FA", "1CEBFF00#05C05D0000FFFFFF"]
    frames = [(int(a, 16), bytes.fromhex(b)) for a, b in (x.split("#") for x in lines)]
    (pgn, sa, data), = feed_all(Reassembler(), frames)
    assert (pgn, sa, len(data)) == (EC1, 0x00, 34)
    assert int.from_bytes(data[19:21], "little") == 260         # SPN 544, bytes 20-21: 260 N.m


def test_rts_session_and_interleaved_senders():
    tp = Reassembler()
    a, b = bytes(range(100, 120)), bytes(range(200, 230))
    frames = [cm(0x03, 0x90, 16, len(a), 0xFECA), cm(0x17, 0xFF, 32, len(b), 0xFEDA)]
    da, db = dts(0x03, 0x90, a), dts(0x17, 0xFF, b)
    for k in range(max(len(da), len(db))):
        frames += da[k:k + 1] + db[k:k + 1]
    assert feed_all(tp, frames) == [(0xFECA, 0x03, a), (0xFEDA, 0x17, b)]


def test_bad_sequences_abort_and_bad_announcements_give_nothing():
    seq = dts(0x00, 0xFF, PAYLOAD)
    # a packet missing
    assert feed_all(Reassembler(), [cm(0x00, 0xFF, 32, 34, EC1), seq[0], seq[2], seq[3], seq[4]]) == []
    # a repeated packet is ignored
    assert len(feed_all(Reassembler(), [cm(0x00, 0xFF, 32, 34, EC1), seq[0], seq[0], *seq[1:]])) == 1
    # an abort from the receiver's side drops the session
    abort = (j1939.make_id(7, PGN_TP_CM, 0xFF, 0x00), bytes([255, 1, 0xFF, 0xFF, 0xFF]) + EC1.to_bytes(3, "little"))
    assert feed_all(Reassembler(), [cm(0x00, 0xFF, 32, 34, EC1), seq[0], abort, *seq[1:]]) == []
    # sizes below 9 or above 1785, packets not matching the size, a PGN beyond 18 bits
    for c in (cm(0x00, 0xFF, 32, 8, EC1), cm(0x00, 0xFF, 32, 1786, EC1), cm(0x00, 0xFF, 32, 34, 1 << 20)):
        assert feed_all(Reassembler(), [c, *seq]) == []
    wrong = (cm(0x00, 0xFF, 32, 34, EC1)[0], bytes([32, 34, 0, 4, 0xFF]) + EC1.to_bytes(3, "little"))
    assert feed_all(Reassembler(), [wrong, *seq]) == []
    # data frames without an announcement, and frames of other lengths
    assert feed_all(Reassembler(), seq) == []
    assert Reassembler().feed(seq[0][0], seq[0][1][:7]) is None


def test_with_reassembled_yields_wanted_messages_after_their_last_packet():
    frames = [Frame(1.0 + 0.05 * i, "can0", c, True, d)
              for i, (c, d) in enumerate([cm(0x00, 0xFF, 32, 34, EC1), *dts(0x00, 0xFF, PAYLOAD)])]
    out = list(with_reassembled(frames, lambda pgn: pgn == EC1))
    assert out[:6] == frames and len(out) == 7
    msg = out[6]
    assert msg.t == frames[-1].t and j1939.parse_id(msg.can_id)[1:3] == (EC1, 0x00) and msg.data == PAYLOAD
    assert list(with_reassembled(frames, lambda pgn: False)) == frames
