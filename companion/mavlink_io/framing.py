"""MAVLink frames cut out of a byte stream (serial, TCP), for the companion's link and the bundled vehicle.

A datagram carries whole frames; a stream carries bytes. :class:`StreamFramer` keeps what it was fed and hands back
complete frames whose CRC checks out, in order, each handled by the links as a one-frame datagram. A partial frame
waits for the next read. Anything that does not check out is garbage: the framer steps one byte past the start
marker it tried and looks for the next one (resynchronisation). A false marker whose "frame" is still incomplete is
given up as soon as a whole valid frame follows it, so noise never holds real frames back.

A frame is accepted when: MAVLink 2 (0xFD) with incompatibility flags 0 or 1 (signed: 13 signature bytes follow
the CRC, not checked here), or MAVLink 1 (0xFE); a message id whose CRC extra is known (common or ArduPilot
dialect); the CRC right. Frames of other ids cannot be told from noise and are skipped as garbage.
"""

from __future__ import annotations

from companion.mavlink_io.codec import crc_extra_of, crc_mcrf4xx

STX_V2 = 0xFD
STX_V1 = 0xFE
SIGNATURE_LEN = 13
MAX_FRAME = 10 + 255 + 2 + SIGNATURE_LEN  # the longest frame: a full signed MAVLink 2 one (280 bytes)

_EXTRA: dict[int, bytes | None] = {}


def _crc_extra(msgid: int) -> bytes | None:
    """The CRC extra byte of ``msgid`` (None: unknown id), cached: the common dialect's, else ArduPilot's (its own
    messages are framed as on UDP, where they reach the handler as unknown messages, not as garbage)."""
    try:
        return _EXTRA[msgid]
    except KeyError:
        pass
    try:
        extra: bytes | None = bytes((crc_extra_of(msgid),))
    except KeyError:
        from pymavlink.dialects.v20 import ardupilotmega  # imported on the first id common lacks (0.2 s)

        cls = ardupilotmega.mavlink_map.get(msgid)
        extra = None if cls is None else bytes((cls.crc_extra,))
    _EXTRA[msgid] = extra
    return extra


class StreamFramer:
    """Whole, CRC-checked MAVLink frames out of stream chunks; ``garbage_bytes`` and ``garbage_runs`` count what was
    skipped (a run: consecutive skipped bytes, counted when it ends or when a chunk ends inside it)."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.garbage_bytes = 0
        self.garbage_runs = 0
        self.frames = 0

    @property
    def held(self) -> int:
        """Bytes waiting for the rest of their frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        """Add ``data``; return the frames now complete, in order."""
        buf = self._buf
        buf += data
        out: list[bytes] = []
        i, n = 0, len(buf)
        skip_from = -1  # start of the current run of garbage
        while i < n:
            size = _frame_size(buf, i, n)
            if size > 0:
                if skip_from >= 0:
                    self._garbage(i - skip_from)
                    skip_from = -1
                out.append(bytes(buf[i : i + size]))
                self.frames += 1
                i += size
            elif size == 0 and not _complete_frame_after(buf, i, n):  # may still be a frame: wait for more bytes
                break
            else:  # no frame here, or a "frame" still incomplete while a whole one follows it: a false start
                if skip_from < 0:
                    skip_from = i
                i += 1
        if skip_from >= 0:
            self._garbage(i - skip_from)
        del buf[:i]
        return out

    def _garbage(self, nbytes: int) -> None:
        self.garbage_bytes += nbytes
        self.garbage_runs += 1

    def clear(self) -> None:
        """Forget a partial frame (the stream was reopened)."""
        self._buf.clear()


def _complete_frame_after(buf: bytearray, i: int, n: int) -> bool:
    """True if a whole valid frame starts after ``i`` and ends within the buffer: then the incomplete "frame" at
    ``i`` is a false start (a real one would contain that frame, CRC and all, by chance), not one to wait for."""
    j = i + 1
    while j < n:
        b = buf[j]
        if b in (STX_V2, STX_V1) and _frame_size(buf, j, n) > 0:
            return True
        j += 1
    return False


def _frame_size(buf: bytearray, i: int, n: int) -> int:
    """At ``buf[i]``: the size of a valid frame there (> 0), 0 if one may be there but is not complete yet, -1 if
    ``buf[i]`` starts no valid frame."""
    stx = buf[i]
    if stx == STX_V2:
        if i + 10 > n:
            return 0 if i + 3 > n or buf[i + 2] <= 1 else -1
        flags = buf[i + 2]
        if flags > 1:
            return -1
        extra = _crc_extra(buf[i + 7] | (buf[i + 8] << 8) | (buf[i + 9] << 16))
        if extra is None:
            return -1
        end = i + 12 + buf[i + 1]
        total = end - i + (SIGNATURE_LEN if flags else 0)
    elif stx == STX_V1:
        if i + 6 > n:
            return 0
        extra = _crc_extra(buf[i + 5])
        if extra is None:
            return -1
        end = i + 8 + buf[i + 1]
        total = end - i
    else:
        return -1
    if i + total > n:
        return 0
    crc = buf[end - 2] | (buf[end - 1] << 8)
    return total if crc_mcrf4xx(bytes(buf[i + 1 : end - 2]) + extra) == crc else -1
