"""MAVLink 2 message signing, as the MAVLink specification defines it, for both ends of a link.

A signed frame is an ordinary MAVLink 2 frame whose ``incompat_flags`` has bit 0x01 (``IFLAG_SIGNED``) set
(the CRC covers that header byte) followed by 13 bytes: link id (1 byte), timestamp (6 bytes, little-endian,
units of 10 µs since 2015-01-01 00:00:00 UTC) and the signature, the first 6 bytes of
SHA-256(secret key (32 bytes) ‖ frame from the 0xFD marker through the CRC ‖ link id ‖ timestamp).

Pure functions over bytes (:func:`sign_frame`, :func:`split_signed`, :func:`signature`, key handling) plus
:class:`SigningVerifier`, which keeps the replay state: the newest timestamp per stream, a stream being the
(system id, component id, link id) of the sender. A frame is accepted when its signature matches and its
timestamp is newer than the last one accepted on its stream; a stream not seen before is accepted unless its
timestamp is more than one minute older than the newest timestamp this end knows (the specification's rule).
Unlike pymavlink's ``check_signature``, the signature is checked *before* the replay state is touched, so a
forged frame cannot poison a stream with a future timestamp. :class:`LinkSigner` produces monotonic outgoing
timestamps (wall clock, never repeating) for one link id.

Key file (``--signing-key FILE``): either 64 hexadecimal characters (the 32-byte key) or any other one-line
passphrase, which is hashed with SHA-256 into the key exactly as MAVProxy's ``signing setup PASSPHRASE`` does.
:func:`write_new_key_file` writes a random key as hex, readable by its owner only.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
import struct
import time
from pathlib import Path

from companion.errors import ConfigError
from companion.mavlink_io.codec import crc_mcrf4xx

IFLAG_SIGNED = 0x01
SIGNATURE_LEN = 13  # link id (1) + timestamp (6) + signature (6)
KEY_LEN = 32
EPOCH_2015_UNIX_S = 1_420_070_400  # 2015-01-01T00:00:00Z
NEW_STREAM_MAX_AGE = 6_000_000  # one minute in 10 µs units
MAX_SENDERS = 64  # distinct senders counted apart in the dropped-frame tally (the rest together)
_HDR_LEN = 10
_TS = struct.Struct("<Q")


def timestamp_from_unix(unix_s: float) -> int:
    """MAVLink signing timestamp (10 µs units since 2015-01-01 UTC) of a Unix time in seconds."""
    return max(0, int((unix_s - EPOCH_2015_UNIX_S) * 100_000))


def signature(key: bytes, frame_to_crc: bytes, link_id: int, timestamp: int) -> bytes:
    """The 6 signature bytes of a frame (marker through CRC, signed flag already set in the header)."""
    h = hashlib.sha256(key)
    h.update(frame_to_crc)
    h.update(bytes((link_id & 0xFF,)))
    h.update(_TS.pack(timestamp)[:6])
    return h.digest()[:6]


def sign_frame(frame: bytes, key: bytes, link_id: int, timestamp: int, crc_extra: int) -> bytes:
    """Sign one unsigned MAVLink 2 ``frame``: set ``IFLAG_SIGNED``, recompute the CRC with the message's
    ``crc_extra``, append link id, timestamp and signature. Raises ValueError for anything else."""
    if len(frame) < _HDR_LEN + 2 or frame[0] != 0xFD or len(frame) != _HDR_LEN + frame[1] + 2:
        raise ValueError("not one complete MAVLink 2 frame")
    if frame[2] & IFLAG_SIGNED:
        raise ValueError("frame is already signed")
    body = bytearray(frame[:-2])
    body[2] |= IFLAG_SIGNED
    crc = crc_mcrf4xx(bytes(body[1:]) + bytes((crc_extra,)))
    body += struct.pack("<H", crc)
    tail = bytes((link_id & 0xFF,)) + _TS.pack(timestamp)[:6]
    return bytes(body) + tail + signature(key, bytes(body), link_id, timestamp)


def split_signed(frame: bytes) -> tuple[bytes, int, int, bytes]:
    """(frame without the 13 signature bytes, link id, timestamp, signature) of a signed MAVLink 2 frame."""
    if len(frame) < _HDR_LEN + 2 + SIGNATURE_LEN or not frame[2] & IFLAG_SIGNED:
        raise ValueError("not a signed MAVLink 2 frame")
    core = frame[:-SIGNATURE_LEN]
    link_id = frame[-13]
    timestamp = int.from_bytes(frame[-12:-6], "little")
    return core, link_id, timestamp, frame[-6:]


# ------------------------------------------------------------------------------------------------ keys
def key_from_text(text: str) -> bytes:
    """Key from a key file's text: 64 hex characters → those 32 bytes; otherwise the first line, stripped, is a
    passphrase and the key is its SHA-256 (as MAVProxy's ``signing setup``). Raises ValueError if empty."""
    line = text.strip().splitlines()[0].strip() if text.strip() else ""
    if not line:
        raise ValueError("empty key file (expected 64 hex characters or a passphrase)")
    if len(line) == 2 * KEY_LEN:
        try:
            return bytes.fromhex(line)
        except ValueError:
            pass
    return hashlib.sha256(line.encode("utf-8")).digest()


def load_key_file(path: str | Path) -> bytes:
    """Read a key file (see :func:`key_from_text`); raises :class:`ConfigError` naming the file."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the signing key: {exc}") from None
    try:
        return key_from_text(text)
    except ValueError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def write_new_key_file(path: str | Path) -> bytes:
    """Write a new random 32-byte key as 64 hex characters to ``path`` (mode 0600, refusing to overwrite)."""
    key = secrets.token_bytes(KEY_LEN)
    fd = os.open(str(path), os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="ascii") as fh:
        fh.write(key.hex() + "\n")
    return key


# ------------------------------------------------------------------------------------------------ state
class SigningVerifier:
    """Checks incoming signed frames against one key and keeps the replay window per stream.

    :meth:`admit` is the whole policy of a signing link: a frame is let in when it is signed and fresh, or unsigned
    from a system in ``accept_unsigned`` (a payload that cannot sign, e.g. ArduCopter SITL's slung payload, system
    2, which ArduPilot forwards unsigned); every frame dropped is counted by sender (system, component) and kind,
    and every unsigned frame let in is counted by system (:meth:`summary`, for the report)."""

    def __init__(self, key: bytes, accept_unsigned: tuple[int, ...] = ()) -> None:
        if len(key) != KEY_LEN:
            raise ValueError(f"signing key must be {KEY_LEN} bytes, got {len(key)}")
        self.key = bytes(key)
        self.stream_timestamps: dict[tuple[int, int, int], int] = {}
        self.newest = 0  # newest timestamp accepted (or sent, see note_sent)
        self.accept_unsigned = frozenset(int(s) for s in accept_unsigned)
        self.dropped: dict[tuple[int, int], dict[str, int]] = {}  # (system, component) -> kind -> frames
        self.accepted_unsigned: dict[int, int] = {}  # system -> unsigned frames let in

    def admit(self, frame: bytes) -> str | None:
        """None if one complete MAVLink 2 ``frame`` may be read: signed, authentic and fresh, or unsigned from a
        system in ``accept_unsigned``; else why not (``unsigned``, ``bad_flags``, ``bad_signature``, ``replay``),
        counted under its sender."""
        flags = frame[2]
        if flags == 0 and frame[5] in self.accept_unsigned:
            self.accepted_unsigned[frame[5]] = self.accepted_unsigned.get(frame[5], 0) + 1
            return None
        kind = self.check(frame) if flags == IFLAG_SIGNED else "unsigned" if flags == 0 else "bad_flags"
        if kind is not None:
            self.note_dropped(frame[5], frame[6], kind)
        return kind

    def note_dropped(self, system: int, component: int, kind: str) -> None:
        """Count one frame dropped for its signature (``kind``) under its sender; past
        :data:`MAX_SENDERS` distinct senders (a spoofer can forge any id) the rest share the key (-1, -1)."""
        key = (system, component)
        if key not in self.dropped and len(self.dropped) >= MAX_SENDERS:
            key = (-1, -1)
        kinds = self.dropped.setdefault(key, {})
        kinds[kind] = kinds.get(kind, 0) + 1

    def summary(self) -> dict:
        """For the report: frames dropped by sender ("system/component" -> kind -> count; "other" past
        :data:`MAX_SENDERS`), the systems accepted unsigned and how many of their frames were let in so."""
        return {
            "dropped_by_sender": {("other" if s < 0 else f"{s}/{c}"): dict(k)
                                  for (s, c), k in sorted(self.dropped.items())},
            "dropped": sum(sum(k.values()) for k in self.dropped.values()),
            "accept_unsigned_systems": sorted(self.accept_unsigned),
            "accepted_unsigned": {str(s): n for s, n in sorted(self.accepted_unsigned.items())},
        }

    def check(self, frame: bytes) -> str | None:
        """None if ``frame`` (signed, complete) is authentic and fresh; else "bad_signature" or "replay".
        Accepting updates the stream's timestamp."""
        core, link_id, ts, sig = split_signed(frame)
        if not hmac.compare_digest(signature(self.key, core, link_id, ts), sig):
            return "bad_signature"
        stream = (core[5], core[6], link_id)
        last = self.stream_timestamps.get(stream)
        if last is not None:
            if ts <= last:
                return "replay"
        elif ts + NEW_STREAM_MAX_AGE < self.newest:
            return "replay"
        self.stream_timestamps[stream] = ts
        self.newest = max(self.newest, ts)
        return None

    def note_sent(self, timestamp: int) -> None:
        """Our own outgoing timestamps advance the local clock too (the specification's local timestamp)."""
        self.newest = max(self.newest, timestamp)


class LinkSigner:
    """Signs outgoing frames of one link: strictly increasing timestamps from the wall clock."""

    def __init__(self, key: bytes, link_id: int, clock=time.time) -> None:
        if len(key) != KEY_LEN:
            raise ValueError(f"signing key must be {KEY_LEN} bytes, got {len(key)}")
        self.key = bytes(key)
        self.link_id = link_id & 0xFF
        self._clock = clock
        self.timestamp = 0

    def next_timestamp(self) -> int:
        """max(last + 1, now): monotonic even if the wall clock steps back."""
        self.timestamp = max(self.timestamp + 1, timestamp_from_unix(self._clock()))
        return self.timestamp

    def sign(self, frame: bytes, crc_extra: int) -> bytes:
        """The signed version of one unsigned frame."""
        return sign_frame(frame, self.key, self.link_id, self.next_timestamp(), crc_extra)


def _main(argv: list[str]) -> int:
    """``python -m companion.mavlink_io.signing keygen FILE``: write a new random key file."""
    if len(argv) != 2 or argv[0] != "keygen":
        print("usage: python -m companion.mavlink_io.signing keygen FILE")
        return 2
    try:
        write_new_key_file(argv[1])
    except FileExistsError:
        print(f"{argv[1]}: exists; not overwritten")
        return 2
    print(f"wrote a new 32-byte MAVLink signing key to {argv[1]} (mode 0600)")
    return 0


if __name__ == "__main__":  # pragma: no cover - thin CLI shell
    import sys

    raise SystemExit(_main(sys.argv[1:]))
