"""A received datagram (or one stream frame) cut into its MAVLink 2 frames and decoded, on the hot path.

:func:`split_unsigned`: a datagram made only of complete, unsigned, CRC-valid MAVLink 2 frames of known messages
(what a vehicle sends), decoded by :func:`~companion.mavlink_io.codec.decode_lite`; None for anything else, which
the link hands to pymavlink's own parser. :func:`split_signed`: with signing on, the frames whose signature and
timestamp check out (:class:`~companion.mavlink_io.signing.SigningVerifier`); the rest counted and dropped.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from companion.mavlink_io import signing
from companion.mavlink_io.codec import STX_V2 as _STX_V2
from companion.mavlink_io.codec import check_crc, decode_lite

MIN_FRAME = 12  # MAVLink 2 header + CRC (bytes)


def split_unsigned(data: bytes, frames_only: bool = False) -> list[tuple[bytes, Any]] | None:
    """(frame, message) for each frame of a datagram made only of complete, unsigned MAVLink 2 frames of known,
    CRC-valid messages; None for anything else (empty, garbage, MAVLink 1, signed, cut short, unknown id, bad
    CRC). ``frames_only``: the caller decodes the checked frames itself: (frame, None), no message object."""
    n = len(data)
    if n == 0:
        return None
    out = []
    i = 0
    while i < n:
        if data[i] != _STX_V2 or i + MIN_FRAME > n or data[i + 2] != 0:
            return None
        end = i + MIN_FRAME + data[i + 1]
        if end > n:
            return None
        frame = data[i:end]
        if frames_only:
            if not check_crc(frame, frame[7] | (frame[8] << 8) | (frame[9] << 16)):
                return None
            out.append((frame, None))
            i = end
            continue
        try:
            msg = decode_lite(frame)
        except Exception:  # FrameError, or a value pymavlink's constructor refuses
            return None
        out.append((frame, msg))
        i = end
    return out


def split_signed(data: bytes, verifier: signing.SigningVerifier,
                 count: Callable[..., None]) -> list[tuple[bytes, Any]]:
    """With signing on: (frame as received, message) for the datagram's frames whose signature and timestamp
    check out; unsigned, forged and replayed frames and anything unframed are counted (``count(kind, detail)``)
    and dropped."""
    out = []
    i, n = 0, len(data)
    while i < n:
        if data[i] != _STX_V2 or i + MIN_FRAME > n:
            if data[i] == 0xFE and i + 5 <= n:  # MAVLink 1 cannot be signed: dropped, counted by sender
                verifier.note_dropped(data[i + 3], data[i + 4], "unsigned")
            count("unsigned" if data[i] == 0xFE else "garbage")
            return out
        flags = data[i + 2]
        total = MIN_FRAME + data[i + 1] + (signing.SIGNATURE_LEN if flags & signing.IFLAG_SIGNED else 0)
        frame = data[i : i + total]
        i += total
        if len(frame) < total:
            count("truncated")
            return out
        kind = verifier.admit(frame)  # signed and fresh, or unsigned from a system let in so
        if kind is not None:
            count(kind, f"frame from system {frame[5]} component {frame[6]}")
            continue
        try:  # decoded without its signature, recorded with it (a .tlog frame is the frame as received)
            out.append((frame, decode_lite(frame[: -signing.SIGNATURE_LEN] if flags else frame)))
        except Exception as exc:  # bad CRC or unknown id inside a valid signature: count, never raise
            count("undecodable", repr(exc)[:120])
    return out
