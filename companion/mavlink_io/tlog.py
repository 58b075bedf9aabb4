"""The .tlog: every MAVLink frame a link sent or received, as ground stations record them.

Each record is an 8-byte big-endian UNIX time stamp in microseconds followed by the raw frame (the format
QGroundControl and MAVProxy write and ``mavlogdump.py`` reads). :class:`TlogWriter` writes one frame a record,
off the event loop; :func:`tlog_frames` and :func:`tlog_messages` read any .tlog back.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from companion.disk_writer import DiskWriter
from companion.mavlink_io import signing
from companion.mavlink_io.codec import STX_V2 as _STX_V2
from companion.mavlink_io.codec import FrameError, decode_lite

_MIN_FRAME = 12  # MAVLink 2 header + CRC

_TLOG_STAMP = struct.Struct(">Q")


class TlogWriter:
    """Append-only .tlog: each record is a big-endian uint64 UNIX time in µs followed by the frame bytes.

    Records collect in memory and go to a :class:`~companion.disk_writer.DiskWriter` thread every
    ``HANDOVER_S`` or ``HANDOVER_BYTES``, whichever comes first: the event loop never waits for the disk.
    """

    HANDOVER_S = 0.25
    HANDOVER_BYTES = 64 * 1024

    def __init__(self, path: Path) -> None:
        self.path = path
        self._writer = DiskWriter("tlog")
        self._writer.create(path)
        self._buf = bytearray()
        self._handed_at = time.monotonic()
        self._closed = False

    def write(self, frame: bytes) -> None:
        if self._closed:
            return
        self._buf += _TLOG_STAMP.pack(int(time.time() * 1e6))
        self._buf += frame
        mono = time.monotonic()
        if len(self._buf) >= self.HANDOVER_BYTES or mono - self._handed_at >= self.HANDOVER_S:
            self._hand_over(mono)

    def _hand_over(self, mono: float) -> None:
        if self._buf:
            self._writer.append(self.path, bytes(self._buf))
            self._buf.clear()
        self._handed_at = mono

    def close(self) -> None:
        if not self._closed:
            self._hand_over(time.monotonic())
            self._closed = True
            self._writer.close()


_STX_V1 = 0xFE


def tlog_frames(path: Path) -> list[tuple[float, bytes]]:
    """(UNIX time s, one MAVLink frame) for every frame of a .tlog (records: 8-byte big-endian µs + bytes;
    :class:`TlogWriter` writes one frame a record, other tools may write several). A torn or unknown tail ends
    the record; a torn last record is dropped."""
    data = path.read_bytes()
    out: list[tuple[float, bytes]] = []
    i = 0
    while i + _TLOG_STAMP.size <= len(data):
        (t_us,) = _TLOG_STAMP.unpack_from(data, i)
        i += _TLOG_STAMP.size
        while i < len(data):  # the record runs until the next frame start we can size; frames are self-delimiting
            stx = data[i]
            if stx == _STX_V2 and i + 3 <= len(data):
                n = _MIN_FRAME + data[i + 1] + (signing.SIGNATURE_LEN if data[i + 2] & signing.IFLAG_SIGNED else 0)
            elif stx == _STX_V1 and i + 2 <= len(data):
                n = 8 + data[i + 1]
            else:
                break
            if i + n > len(data):
                return out
            out.append((t_us * 1e-6, data[i : i + n]))
            i += n
            if i + _TLOG_STAMP.size <= len(data) and data[i] not in (_STX_V1, _STX_V2):
                break  # the next record's time stamp
        else:
            break
    return out


def tlog_messages(path: Path) -> Iterator[tuple[float, Any]]:
    """(UNIX time s, decoded message) for every frame of a .tlog the codec decodes (signed ones read without
    their signature, which is not checked here); others are skipped."""
    for t_s, frame in tlog_frames(path):
        if frame[0] == _STX_V2 and frame[2] & signing.IFLAG_SIGNED:
            frame = frame[: -signing.SIGNATURE_LEN]
        try:
            yield t_s, decode_lite(frame)
        except FrameError:
            continue
