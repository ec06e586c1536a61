"""Mutation engine shared by every harness: byte-level and token-level.

All randomness comes from the ``random.Random`` passed in, so a run is
reproducible from its seed.  Nothing here knows the project's formats; the
format-aware mutations (re-checksummed NMEA fields, candump fields, CSV
cells, TOML values) live in :mod:`fuzz.targets`.
"""

from __future__ import annotations

import random

# Values that tend to break number parsing, range checks and type conversion.
INTERESTING_TEXT: tuple[str, ...] = (
    "", "0", "-0", "1", "-1", "+5", " 5 ", "1.5", "-1.5", ".", "-", "+", "e", "1e", "1_000", "0x10", "0b1",
    "nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e308", "1e309", "-1e309", "4.9e-324", "1e-400",
    "7", "8", "9", "23", "24", "59", "60", "61", "99", "100", "127", "128", "255", "256",
    "32767", "32768", "-32768", "-32769", "65535", "65536", "2147483647", "2147483648", "4294967296",
    "9223372036854775807", "9223372036854775808", "18446744073709551616",
    "1e20", "-1e20", "99999999999999999999", "9" * 400, "1" + "0" * 5000,
    "000000", "999999", "235959.99", "240000", "000000.00", "310299", "290200", "010100", "311299",
    "\x00", "\x7f", "\xff", "\u00e9", "\u00bd", "\u0663", "\ufeff", "\u2028", "\r", "\n", "\r\n", "\t",
    ",", "*", "$", "!", "#", "##", "#R", "(", ")", "\"", "'", ";", "=", "[", "]", "{", "}", "\\", "%s", "%n",
)

INTERESTING_INTS: tuple[int, ...] = (
    0, 1, -1, 7, 8, 9, 15, 16, 63, 64, 127, 128, 254, 255, 256, 0x7FF, 0x800, 0xFFFF, 0x10000,
    0x1FFFFFFF, 0x20000000, 0x3FFFFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, 1 << 32, 1 << 63, 1 << 64,
    -(1 << 31), -(1 << 63), 10**20, 10**400,
)

INTERESTING_BYTES: tuple[bytes, ...] = (
    b"\x00", b"\xff", b"\x7f", b"\x80", b"\r", b"\n", b"\r\n", b"\t", b" ", b"\xb5\x62",
    b"\xef\xbb\xbf", b"\xc3\xa9", b"\xed\xa0\x80", b"\xf0\x9f\x9a\x9c", b"\xe2\x80\xa8",
)


def ubx_frame(rng: random.Random, max_payload: int = 64) -> bytes:
    """A u-blox UBX binary message (sync 0xB5 0x62, class, id, length, payload, checksum)."""
    n = rng.randint(0, max_payload)
    body = bytes([rng.choice((0x01, 0x02, 0x05, 0x06, 0x0A, 0x0D, 0x27)), rng.randrange(256)])
    body += n.to_bytes(2, "little") + rng.randbytes(n)
    a = b = 0
    for c in body:
        a = (a + c) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes([a, b])


class Mutator:
    """Byte- and text-level mutations drawn from ``rng``."""

    def __init__(self, rng: random.Random, corpus: list[bytes] | None = None) -> None:
        self.rng = rng
        self.corpus = corpus or [b""]

    # ------------------------------------------------------------ bytes
    def mutate_bytes(self, data: bytes, max_ops: int = 4) -> bytes:
        """Apply 1..max_ops random edits to ``data``."""
        rng = self.rng
        buf = bytearray(data)
        for _ in range(rng.randint(1, max_ops)):
            op = rng.randrange(13)
            n = len(buf)
            if op == 0 and n:  # flip one bit
                i = rng.randrange(n)
                buf[i] ^= 1 << rng.randrange(8)
            elif op == 1 and n:  # random byte
                buf[rng.randrange(n)] = rng.randrange(256)
            elif op == 2:  # insert random bytes
                i = rng.randint(0, n)
                buf[i:i] = rng.randbytes(rng.randint(1, 8))
            elif op == 3:  # insert an interesting byte string
                i = rng.randint(0, n)
                buf[i:i] = rng.choice(INTERESTING_BYTES)
            elif op == 4:  # insert an interesting text token
                i = rng.randint(0, n)
                buf[i:i] = rng.choice(INTERESTING_TEXT).encode("utf-8", "surrogatepass")
            elif op == 5 and n:  # delete a range
                i = rng.randrange(n)
                del buf[i : i + rng.randint(1, max(1, min(16, n - i)))]
            elif op == 6 and n:  # duplicate a range
                i = rng.randrange(n)
                j = min(n, i + rng.randint(1, 16))
                buf[j:j] = buf[i:j]
            elif op == 7 and n:  # cut (a line cut mid-way)
                del buf[rng.randrange(n) :]
            elif op == 8:  # splice with another seed
                other = rng.choice(self.corpus)
                i = rng.randint(0, n)
                j = rng.randint(0, len(other))
                buf = buf[:i] + other[j:]
            elif op == 9 and n:  # replace a run of digits by an interesting number
                digits = [k for k in range(n) if 48 <= buf[k] <= 57]
                if digits:
                    i = rng.choice(digits)
                    j = i
                    while j < n and 48 <= buf[j] <= 57:
                        j += 1
                    buf[i:j] = rng.choice(INTERESTING_TEXT).encode("utf-8", "surrogatepass")
            elif op == 10 and n:  # swap case of letters / hex digits
                i = rng.randrange(n)
                buf[i : i + 8] = bytes(buf[i : i + 8]).swapcase()
            elif op == 11 and n:  # overwrite with an arithmetic neighbour
                i = rng.randrange(n)
                buf[i] = (buf[i] + rng.choice((-1, 1, -16, 16))) & 0xFF
            elif op == 12:  # insert a UBX binary message
                i = rng.randint(0, n)
                buf[i:i] = ubx_frame(rng)
        return bytes(buf)

    def random_bytes(self, max_len: int = 120) -> bytes:
        """Random bytes, biased to printable ASCII half of the time."""
        rng = self.rng
        n = rng.randint(0, max_len)
        if rng.random() < 0.5:
            return bytes(rng.randrange(32, 127) for _ in range(n))
        return rng.randbytes(n)

    # ------------------------------------------------------------ text
    def mutate_text(self, text: str, max_ops: int = 4) -> str:
        """:meth:`mutate_bytes` on the UTF-8 form, decoded back with replacement."""
        return self.mutate_bytes(text.encode("utf-8"), max_ops).decode("utf-8", "replace")

    def token(self) -> str:
        """An interesting text token."""
        return self.rng.choice(INTERESTING_TEXT)

    def number_text(self) -> str:
        """A number-like token: interesting, or a random int / float of any magnitude."""
        rng = self.rng
        r = rng.random()
        if r < 0.4:
            return self.token()
        if r < 0.7:
            return str(rng.randint(-(10 ** rng.randint(0, 25)), 10 ** rng.randint(0, 25)))
        return repr(rng.uniform(-1, 1) * 10.0 ** rng.randint(-30, 308)) if rng.random() < 0.9 else repr(rng.random())
