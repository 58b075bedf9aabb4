"""A pair of connected pseudo-terminals: a serial cable between two programs on one machine.

``socat -d -d pty,raw,echo=0,link=A pty,raw,echo=0,link=B`` does this; where socat is missing (some CI images),
``python -m lab.pty_pair A B`` does the same in Python: two pty masters, a relay copying bytes between them,
``A`` and ``B`` symbolic links to their slave devices, raw mode (no echo, no line editing, 8 bits). Both are real
terminals a serial program opens like ``/dev/ttyUSB0``. A baud rate set on a pty is nominal: the kernel moves
bytes as fast as the processes read them (no 921600 bit/s limit).

The relay keeps both slaves open itself, so bytes written before the other program opened its end wait in the
terminal's buffer (4 KiB; what does not fit is dropped and counted), and a program closing its end does not end
the pair; SIGTERM/SIGINT end it (links removed). Killing the relay takes both devices away (the programs read
EIO or end of file: a serial device that disappeared).

:class:`PtyPair` starts one (socat when on PATH, else this relay) for tests and benches.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import signal
import subprocess
import sys
import time
import tty
from pathlib import Path

from companion import proclife


def _raw_pty() -> tuple[int, int]:
    """A pty (master, slave), raw, the master non-blocking."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return master, slave


def relay(link_a: Path, link_b: Path, ready=None) -> int:
    """Make the pair, link it at ``link_a``/``link_b``, copy bytes both ways until SIGTERM/SIGINT; returns 0."""
    (ma, sa), (mb, sb) = _raw_pty(), _raw_pty()
    stop = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.append(True))
    links = [(Path(link_a), os.ttyname(sa)), (Path(link_b), os.ttyname(sb))]
    dropped = 0
    try:
        for link, dev in links:
            with contextlib.suppress(FileNotFoundError):
                link.unlink()
            link.symlink_to(dev)
        if ready is not None:
            ready(links)
        other = {ma: mb, mb: ma}
        while not stop:
            try:
                readable, _, _ = select.select((ma, mb), (), (), 0.2)
            except InterruptedError:
                continue
            for fd in readable:
                try:
                    data = os.read(fd, 65536)
                except (BlockingIOError, InterruptedError):
                    continue
                try:
                    n = os.write(other[fd], data)
                except BlockingIOError:
                    n = 0
                dropped += len(data) - n
    finally:
        for link, _dev in links:
            with contextlib.suppress(FileNotFoundError):
                link.unlink()
        for fd in (ma, sa, mb, sb):
            os.close(fd)
    if dropped:
        print(f"pty_pair: dropped {dropped} bytes (the other end did not read)", file=sys.stderr)
    return 0


class PtyPair:
    """``with PtyPair(a, b) as pair:`` two connected pseudo-terminals at paths ``a`` and ``b`` (socat when on PATH
    and ``use_socat`` is not False, else :func:`relay` in a child process); stopped at exit."""

    def __init__(self, a: Path, b: Path, use_socat: bool | None = None) -> None:
        self.a, self.b = Path(a), Path(b)
        self.use_socat = shutil.which("socat") is not None if use_socat is None else use_socat
        self.proc: subprocess.Popen | None = None

    @property
    def tool(self) -> str:
        """What makes the pair: "socat" or "relay"."""
        return "socat" if self.use_socat else "relay"

    def start(self, timeout_s: float = 10.0) -> PtyPair:
        if self.use_socat:
            argv = ["socat", "-d", "-d", f"pty,raw,echo=0,link={self.a}", f"pty,raw,echo=0,link={self.b}"]
        else:
            argv = [sys.executable, "-m", "lab.pty_pair", str(self.a), str(self.b)]
        self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, preexec_fn=proclife.preexec(),
                                     cwd=Path(__file__).resolve().parents[1])
        end = time.monotonic() + timeout_s
        while not (self.a.exists() and self.b.exists()):
            if self.proc.poll() is not None or time.monotonic() > end:
                self.stop()
                raise RuntimeError(f"{self.tool} made no pty pair at {self.a}, {self.b}")
            time.sleep(0.01)
        return self

    def stop(self, sig: int = signal.SIGTERM) -> None:
        """End the pair with ``sig`` (SIGKILL: the devices vanish at once, links left dangling) and wait."""
        p = self.proc
        if p is not None and p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                p.send_signal(sig)
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)

    def __enter__(self) -> PtyPair:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main(argv: list[str] | None = None) -> int:
    """``python -m lab.pty_pair A B``: a pty pair linked at A and B until SIGTERM/SIGINT."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        print("usage: python -m lab.pty_pair LINK_A LINK_B", file=sys.stderr)
        return 2
    return relay(Path(args[0]), Path(args[1]),
                 ready=lambda links: print(" ".join(f"{a}={d}" for a, d in links), flush=True))


if __name__ == "__main__":
    sys.exit(main())
