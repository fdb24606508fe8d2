"""A noisy serial line from the virtual GRBL to its client: replies lost or garbled, with a seeded draw per line.

A USB cable picking up a motor driver's noise, an overrun host buffer or a flaky connector loses whole lines or
corrupts a byte of one. GRBL has no checksum, so a client sees exactly that: an ``ok`` that never comes, a
status report that never comes, or a line with a byte that is not a character (the framing error a corrupted
byte on a UART gives, kept out of the printable range so the client can tell; silently wrong digits are beyond
this model). Draws are seeded: a test sees the same noise every time.
"""

from __future__ import annotations

import random


class LineNoise:
    """Each line handed to ``carry`` is lost with probability ``drop`` or one byte garbled with ``garble``."""

    def __init__(self, drop: float = 0.0, garble: float = 0.0, seed: int = 0) -> None:
        for name, p in (("drop", drop), ("garble", garble)):
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"virtual GRBL line noise: {name} = {p!r}, expected a probability in [0, 1]")
        if drop + garble > 1.0:
            raise ValueError(f"virtual GRBL line noise: drop + garble = {drop + garble!r}, expected at most 1")
        self.drop, self.garble = float(drop), float(garble)
        self._rng = random.Random(seed)
        self.dropped = 0  # lines lost so far
        self.garbled = 0  # lines delivered with a corrupted byte so far

    def carry(self, line: bytes) -> bytes:
        """What arrives of ``line`` (its CR LF included): nothing, the line, or the line with one byte corrupted."""
        u = self._rng.random()
        if u < self.drop:
            self.dropped += 1
            return b""
        text = line.rstrip(b"\r\n")
        if u < self.drop + self.garble and text:
            self.garbled += 1
            i = self._rng.randrange(len(text))
            # Bit 7 set: no longer ASCII, which a UART's framing error also tends to leave.
            return text[:i] + bytes([text[i] | 0x80]) + text[i + 1 :] + line[len(text) :]
        return line
