"""Starting Rerun viewers: the native window, or Rerun's web viewer served on a loopback port.

Both run the ``rerun`` executable that ships inside the rerun-sdk wheel, as a child process we own, bound
to 127.0.0.1 (the SDK's in-process web server listens on every interface, so it is not used). The viewer
process listens for the recording on a gRPC port (``rerun+http://127.0.0.1:<grpc>/proxy``); the web viewer
is at ``http://127.0.0.1:<web>/?url=<that>``. A headless machine (no ``DISPLAY`` / ``WAYLAND_DISPLAY`` on
Linux) gets the web viewer.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from companion import proclife
from companion.errors import ConfigError, LinkError

log = logging.getLogger(__name__)

DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876
HOST = "127.0.0.1"
VIEW_MODES = ("auto", "native", "web")


def rerun_executable() -> str:
    """The ``rerun`` viewer executable (the one in rerun-sdk's wheel first, then ``PATH``)."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    found = shutil.which("rerun")
    if found is None:
        raise ConfigError("the Rerun viewer is not installed: pip install rerun-sdk")
    return found


def has_display() -> bool:
    """Whether a native window can open here."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def resolve_mode(mode: str) -> str:
    """``auto`` → ``native`` with a display, else ``web``."""
    if mode not in VIEW_MODES:
        raise ConfigError(f"--view: must be one of {', '.join(VIEW_MODES)}, got {mode!r}")
    if mode == "auto":
        return "native" if has_display() else "web"
    return mode


def port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((HOST, port))
        except OSError:
            return False
    return True


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((HOST, 0))
        return int(s.getsockname()[1])


def pick_port(wanted: int | None, default: int) -> int:
    """``wanted`` if given (it must be free), else ``default`` when free, else any free port."""
    if wanted:
        if not port_free(wanted):
            raise LinkError(f"port {wanted} on {HOST} is in use")
        return wanted
    return default if port_free(default) else free_port()


def _wait_listening(port: int, proc: subprocess.Popen, timeout_s: float) -> None:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if proc.poll() is not None:
            raise LinkError(f"the Rerun viewer exited with code {proc.returncode} before listening on {port}")
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.2)
            if s.connect_ex((HOST, port)) == 0:
                return
        time.sleep(0.05)
    raise LinkError(f"the Rerun viewer did not listen on {HOST}:{port} within {timeout_s:.0f} s")


@dataclass
class ViewerProcess:
    """A viewer we started: its process, the gRPC URL recordings stream to, the web URL (web mode)."""

    proc: subprocess.Popen
    grpc_url: str
    web_url: str | None = None
    detached: bool = False

    def close(self, timeout_s: float = 3.0) -> None:
        """Stop the viewer (SIGTERM, then SIGKILL); a detached native window is left to the user."""
        if self.detached or self.proc.poll() is not None:
            return
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGTERM)
        try:
            self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout_s)

    def wait(self) -> int:
        """Until the viewer exits (or Ctrl-C, or SIGTERM: the viewer is stopped, 130): its exit code."""
        try:
            with proclife.sigterm_as_interrupt():
                return self.proc.wait()
        except KeyboardInterrupt:
            self.close()
            return 130


def grpc_url_for(port: int) -> str:
    return f"rerun+http://{HOST}:{port}/proxy"


def web_url_for(web_port: int, grpc_url: str) -> str:
    return f"http://{HOST}:{web_port}/?url={urllib.parse.quote(grpc_url, safe='')}"


def start_web_viewer(*, web_port: int | None = None, grpc_port: int | None = None, files: Sequence[Path] = (),
                     timeout_s: float = 30.0, log_file: Path | None = None) -> ViewerProcess:
    """``rerun --serve-web`` on 127.0.0.1: the web viewer on ``web_port`` (default 9090, else a free port) and
    the gRPC proxy on ``grpc_port`` (default 9876, else free). ``files`` (.rrd) are loaded and served."""
    wp = pick_port(web_port, DEFAULT_WEB_PORT)
    gp = pick_port(grpc_port, DEFAULT_GRPC_PORT)
    if gp == wp:
        gp = free_port()
    cmd = [rerun_executable(), "--serve-web", "--bind", HOST, "--port", str(gp), "--web-viewer-port", str(wp),
           *map(str, files)]
    proc = _popen(cmd, log_file, detach=False)
    try:
        _wait_listening(wp, proc, timeout_s)
        _wait_listening(gp, proc, timeout_s)
    except BaseException:
        ViewerProcess(proc, "").close()
        raise
    grpc = grpc_url_for(gp)
    return ViewerProcess(proc, grpc, web_url_for(wp, grpc))


def start_native_viewer(*, grpc_port: int | None = None, files: Sequence[Path] = (), detach: bool = True,
                        timeout_s: float = 30.0, log_file: Path | None = None) -> ViewerProcess:
    """The native Rerun window listening on 127.0.0.1:``grpc_port``; ``detach``: it outlives us (the user
    closes it)."""
    gp = pick_port(grpc_port, DEFAULT_GRPC_PORT)
    cmd = [rerun_executable(), "--bind", HOST, "--port", str(gp), *map(str, files)]
    if not files:
        cmd.append("--expect-data-soon")
    proc = _popen(cmd, log_file, detach=detach)
    if not files:
        _wait_listening(gp, proc, timeout_s)
    return ViewerProcess(proc, grpc_url_for(gp), None, detached=detach)


def start_viewer(mode: str, *, web_port: int | None = None, grpc_port: int | None = None,
                 files: Sequence[Path] = (), log_file: Path | None = None) -> ViewerProcess:
    """A viewer in ``mode`` (``auto``, ``native``, ``web``)."""
    if resolve_mode(mode) == "web":
        return start_web_viewer(web_port=web_port, grpc_port=grpc_port, files=files, log_file=log_file)
    return start_native_viewer(grpc_port=grpc_port, files=files, log_file=log_file)


def _popen(cmd: list[str], log_file: Path | None, *, detach: bool) -> subprocess.Popen:
    out = open(log_file, "ab") if log_file is not None else subprocess.DEVNULL  # noqa: SIM115
    try:
        log.info("starting the Rerun viewer: %s", " ".join(cmd))
        # Its own process group: a Ctrl-C in the terminal reaches us first, and we stop it last. Unless it is a
        # detached window (the user's to close), it dies with us, SIGKILL included (companion.proclife).
        return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=out, start_new_session=True,
                                preexec_fn=None if detach else proclife.preexec())
    finally:
        if log_file is not None:
            out.close()  # type: ignore[union-attr]


def optimize_recording(path: Path, timeout_s: float = 60.0) -> bool:
    """Compact a finished .rrd in place with ``rerun rrd optimize`` (merges the many small chunks a live
    recording is written in: about half the size for a lockstep flight, more in real time). False, with the
    original kept, when it fails."""
    tmp = path.with_suffix(".optimizing.rrd")
    try:
        res = subprocess.run([rerun_executable(), "rrd", "optimize", str(path), "-o", str(tmp)],
                             stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout_s,
                             preexec_fn=proclife.preexec())
        if res.returncode != 0 or not tmp.is_file() or tmp.stat().st_size == 0:
            log.warning("rerun rrd optimize failed (exit %s); keeping %s as written: %s", res.returncode, path,
                        res.stderr.strip()[-300:])
            return False
        os.replace(tmp, path)
        return True
    except (OSError, subprocess.TimeoutExpired, ConfigError) as exc:
        log.warning("rerun rrd optimize failed: %s; keeping %s as written", exc, path)
        return False
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
