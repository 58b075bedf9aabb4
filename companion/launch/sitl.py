"""Start the bundled SITL vehicle as a separate process on free loopback ports (for ``fly --sitl``).

The companion never imports the simulator: it runs ``python -m sim_bridge`` and talks MAVLink to it, the
same way it talks to PX4 or ArduPilot. Where the command line or the lab forked the vehicle ahead
(``sim_bridge.prefork``), it hands that child the same arguments instead (:class:`VehicleFork`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import shutil
import signal
import socket
import sys
from pathlib import Path
from typing import Protocol

from companion import proclife
from companion.core.mission import Mission
from companion.errors import LinkError
from companion.launch.forked_child import ForkedChild

log = logging.getLogger(__name__)

VEHICLE_COMMAND = (sys.executable, "-m", "sim_bridge")  #: how the bundled vehicle is started (its arguments follow)
PTY_BAUD = 921600  # nominal on a pseudo-terminal (docs/companion.md, Links)


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def vehicle_toml(mission: Mission) -> str:
    """The mission's vehicle parameters in config/vehicle.toml format."""
    lines = ["[vehicle]"] + [f"{k} = {v!r}" for k, v in mission.vehicle.as_dict().items()]
    return "\n".join(lines) + "\n"


class VehicleFork(Protocol):
    """A vehicle process forked ahead of its command line (``sim_bridge.prefork.PreforkedVehicle``): started with
    :meth:`launch` instead of ``python -m sim_bridge``, it skips the interpreter's start and, when warm, its imports
    and kernels."""

    pid: int

    def launch(self, args: list[str], stderr_path: Path) -> int:
        """Become ``python -m sim_bridge *args`` (stdin /dev/null, stderr into ``stderr_path``); the read end of its
        stdout. Raises OSError when the child is gone (reaped by then)."""
        ...

    def discard(self) -> None:
        """Let it go unlaunched (it exits; reaped)."""
        ...


def process_state(pid: int, returncode: int | None) -> dict[str, object]:
    """How a child was doing: ``{"exited": code}`` once it has exited (negative: killed by that signal, with
    ``signal`` its name), else ``{"state": "S (sleeping)", "wchan": kernel function it waits in}`` from Linux's
    ``/proc`` (empty elsewhere). A vehicle that fell silent is told apart from a dead one by this."""
    if returncode is not None:
        out: dict[str, object] = {"exited": returncode}
        if returncode < 0:
            with contextlib.suppress(ValueError):
                out["signal"] = signal.Signals(-returncode).name
        return out
    out = {}
    with contextlib.suppress(OSError):
        status = Path(f"/proc/{pid}/status").read_text()
        out["state"] = next((ln.split(":", 1)[1].strip() for ln in status.splitlines() if ln.startswith("State:")),
                            "?")
    with contextlib.suppress(OSError):
        out["wchan"] = Path(f"/proc/{pid}/wchan").read_text().strip() or "0"
    return out


class _PortTaken(Exception):
    """The vehicle could not bind its ports: another process took them after we chose them."""


class SitlProcess:
    """``async with SitlProcess(mission, workdir) as sitl:`` then connect to ``sitl.companion_url``."""

    def __init__(
        self,
        mission: Mission,
        workdir: Path,
        *,
        lockstep: bool = True,
        extra_args: list[str] | None = None,
        ready_timeout_s: float = 60.0,
        serial: bool = False,
        fork: VehicleFork | None = None,
    ) -> None:
        self.mission = mission
        self.workdir = workdir
        self.lockstep = lockstep
        self.serial = serial  # the onboard link over a pseudo-terminal pair instead of UDP (``fly --sitl --serial``)
        self.pty_pair: asyncio.subprocess.Process | None = None
        self.extra_args = extra_args or []
        self.fork = fork  # used for the first start only (a retry on taken ports execs a fresh one)
        self.ready_timeout_s = ready_timeout_s
        # The companion's socket is bound here and handed to the link, so no other process can take the port
        # between choosing it and using it; the vehicle's ports are retried if another process won the race.
        self.companion_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.companion_sock.bind(("127.0.0.1", 0))
        self.companion_port = self.companion_sock.getsockname()[1]
        self.vehicle_port = free_udp_port()
        self.gcs_port = free_udp_port()
        self.proc: asyncio.subprocess.Process | ForkedChild | None = None
        self.ready_line = ""
        self._stderr_path = workdir / "sitl.log"
        self._stderr = None  # the log file's handle when this process opened it (not for a forked vehicle)
        self.at_stop: dict[str, object] | None = None  # the vehicle as the flight's end found it (:meth:`facts`)

    @property
    def companion_url(self) -> str:
        """Where the companion listens for the vehicle: ``udpin://127.0.0.1:<port>`` (``serial``: its end of the pty
        pair, ``serial://RUN_DIR/pty-companion:921600``)."""
        if self.serial:
            return f"serial://{self.workdir / 'pty-companion'}:{PTY_BAUD}"
        return f"udpin://127.0.0.1:{self.companion_port}"

    def argv(self) -> list[str]:
        """The vehicle's command line."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        vfile = self.workdir / "vehicle.toml"
        vfile.write_text(vehicle_toml(self.mission))
        argv = [
            *VEHICLE_COMMAND,
            "--onboard-port", str(self.vehicle_port),
            "--onboard-remote", f"127.0.0.1:{self.companion_port}",
            "--gcs-port", str(self.gcs_port),
            "--vehicle", str(vfile),
            "--wind", self.mission.wind.model,
            "--wind-scale", repr(self.mission.wind.scale),
        ]
        if self.mission.wind.model not in ("paper", "none"):  # physical wind: all its settings in a file
            wfile = self.workdir / "wind.toml"
            wfile.write_text("\n".join(["[wind]", *self.mission.wind.toml_lines()]) + "\n")
            argv += ["--wind-file", str(wfile)]
        if self.lockstep:
            argv.append("--lockstep")
        if self.serial:
            argv += ["--serial", f"{self.workdir / 'pty-vehicle'}:{PTY_BAUD}"]
        return argv + self.extra_args

    def facts(self) -> dict[str, object]:
        """The report's ``sitl_vehicle``: its pid, how the flight's end found it (``at_stop``: exited by itself, with
        its code, or its scheduler state, e.g. ``T`` for stopped by a signal) and its final exit code."""
        proc = self.proc
        return {"pid": None if proc is None else proc.pid, "at_stop": self.at_stop,
                "exit_code": None if proc is None else proc.returncode}

    async def __aenter__(self) -> SitlProcess:
        if self.serial:
            await self._start_pty_pair()
        for attempt in range(3):
            try:
                await self._start()
                return self
            except _PortTaken:
                log.info("SITL ports taken by another process (attempt %d); choosing others", attempt + 1)
                self.vehicle_port, self.gcs_port = free_udp_port(), free_udp_port()
        self.companion_sock.close()
        await self._stop_pty_pair()
        raise LinkError("could not find free UDP ports for the SITL vehicle")

    async def _spawn(self, argv: list[str]) -> asyncio.subprocess.Process | ForkedChild:
        """The vehicle's process: the forked one when there is one still unused, else ``argv`` executed in its own
        session and tied to this process (started from the event loop's thread), so that it dies with the companion
        however the companion dies, SIGKILL included (docs/companion.md, Process lifetime)."""
        fork, self.fork = self.fork, None
        if fork is not None:
            try:
                stdout_fd = fork.launch(argv[len(VEHICLE_COMMAND):], self._stderr_path)
            except OSError as exc:  # it reaped the child
                log.warning("the vehicle forked ahead is gone (%s); starting a fresh one", exc)
            else:
                return await ForkedChild.attach(fork.pid, stdout_fd)
        self._stderr = self._stderr_path.open("wb")
        return await asyncio.create_subprocess_exec(
            *argv, stdout=asyncio.subprocess.PIPE, stderr=self._stderr, stdin=asyncio.subprocess.DEVNULL,
            start_new_session=True, preexec_fn=proclife.preexec(),
        )

    async def _start(self) -> None:
        argv = self.argv()
        log.info("starting the bundled vehicle%s: %s", " (forked ahead)" if self.fork else "", " ".join(argv))
        # its own session (process group): a terminal's Ctrl-C reaches the companion only, which then holds, lands
        # and stops the vehicle last
        self.proc = await self._spawn(argv)
        assert self.proc.stdout is not None
        try:
            async with asyncio.timeout(self.ready_timeout_s):
                while True:
                    line = await self.proc.stdout.readline()
                    if not line:
                        await self.proc.wait()
                        if self._stderr is not None:
                            self._stderr.close()
                        err = self._stderr_path.read_text(errors="replace")
                        if "Address already in use" in err:
                            raise _PortTaken
                        last = [ln for ln in err.splitlines() if "error:" in ln][-1:]  # its own reason, if it gave one
                        why = f": {last[0].split('error:', 1)[1].strip()}" if last else ""
                        raise LinkError(f"the SITL vehicle exited before it was ready{why}; see {self._stderr_path}")
                    text = line.decode(errors="replace").strip()
                    if text.startswith("SITL READY"):
                        self.ready_line = text
                        break
        except TimeoutError:
            await self._stop(graceful=False)
            raise LinkError(f"the SITL vehicle was not ready within {self.ready_timeout_s:.0f} s") from None
        except _PortTaken:
            raise
        except BaseException:  # e.g. Ctrl-C while it starts: nothing flies yet, so nothing to wait for
            await self._stop(graceful=False)
            raise
        log.info("%s", self.ready_line)

    async def __aexit__(self, *exc: object) -> None:
        await self._stop()

    async def _start_pty_pair(self) -> None:
        """The pseudo-terminal pair of ``serial`` at RUN_DIR/pty-vehicle and RUN_DIR/pty-companion: socat when it is
        on PATH, else ``python -m lab.pty_pair`` (the same in Python); in its own session and tied to this process,
        like the vehicle. A pty's baud rate is nominal (no rate limit)."""
        a, b = self.workdir / "pty-vehicle", self.workdir / "pty-companion"
        argv = (["socat", "-d", "-d", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"] if shutil.which("socat")
                else [sys.executable, "-m", "lab.pty_pair", str(a), str(b)])
        self.workdir.mkdir(parents=True, exist_ok=True)
        log.info("starting the pseudo-terminal pair: %s", " ".join(argv))
        self.pty_pair = await asyncio.create_subprocess_exec(
            *argv, stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.DEVNULL, start_new_session=True, preexec_fn=proclife.preexec())
        for _ in range(1000):
            if a.exists() and b.exists():
                return
            if self.pty_pair.returncode is not None:
                break
            await asyncio.sleep(0.01)
        await self._stop_pty_pair()
        raise LinkError(f"{argv[0]} made no pseudo-terminal pair at {a} and {b}")

    async def _stop_pty_pair(self) -> None:
        proc, self.pty_pair = self.pty_pair, None
        if proc is not None and proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.terminate()
            try:
                async with asyncio.timeout(2.0):
                    await proc.wait()
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                await proc.wait()

    async def _stop(self, graceful: bool = True) -> None:
        """Stop the vehicle: SIGINT and up to 5 s to exit, then SIGKILL; at once with ``graceful=False`` (a
        vehicle still starting, e.g. importing or compiling its model, may not act on SIGINT for seconds)."""
        proc = self.proc
        if proc is not None and self.at_stop is None:
            self.at_stop = process_state(proc.pid, proc.returncode)
        if proc is not None and proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGINT if graceful else signal.SIGKILL)
                if str(self.at_stop.get("state", "")).startswith("T"):  # stopped by a signal: let it act on ours
                    proc.send_signal(signal.SIGCONT)
            try:
                async with asyncio.timeout(5.0):
                    await proc.wait()
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    proc.kill()
                await proc.wait()
        if self.fork is not None:  # never launched (the start failed before it)
            self.fork.discard()
            self.fork = None
        if self._stderr is not None:
            self._stderr.close()
        await self._stop_pty_pair()  # after the vehicle: its serial device stays until it is gone
        self.companion_sock.close()  # the link has its own reference while it is open
