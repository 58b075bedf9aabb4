"""The viewer on the command line: ``fly --view``, ``replay RUN_DIR`` and ``view`` (every vehicle on Zenoh).

Rerun is imported only inside these functions (it takes ≈ 1 s to import), so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from companion.errors import ConfigError

log = logging.getLogger(__name__)

VIEW_HELP = ("show the flight live in Rerun's viewer: auto (default) = native window when there is a display, "
             "else web; web = Rerun's web viewer on 127.0.0.1 (the URL is printed); native = a viewer window")


def add_view_arguments(p: argparse.ArgumentParser) -> None:
    """``fly``'s ``--view [MODE]``, ``--view-port``, ``--no-recording``."""
    g = p.add_argument_group("3-D view and recording")
    g.add_argument("--view", nargs="?", const="auto", default=None, choices=["auto", "native", "web"],
                   metavar="MODE", help=VIEW_HELP)
    g.add_argument("--view-port", type=int, default=None, metavar="PORT",
                   help="web viewer port on 127.0.0.1 (default 9090, or a free port when 9090 is taken)")
    g.add_argument("--no-recording", action="store_true",
                   help="no recording.rrd in the run folder (and no --view): batch flights that need no replay")


class FlightViewSession:
    """The flight's recording (``recording.rrd``) and, with ``--view``, the live viewer. ``with`` closes both:
    the recording is flushed and complete, a web viewer is stopped, a native window stays open."""

    def __init__(self, args: argparse.Namespace, mission: Any, run_dir: Path) -> None:
        self.args = args
        self.mission = mission
        self.run_dir = run_dir
        self.viewer: Any = None
        self.view: Any = None
        self._stats: dict[str, Any] = {}

    def __enter__(self) -> FlightViewSession:
        from companion.viz.flight import RECORDING_FILE, open_flight_recording

        mode = getattr(self.args, "view", None)
        grpc_url = None
        if mode:
            from companion.viz.viewer import start_viewer

            self.viewer = start_viewer(mode, web_port=getattr(self.args, "view_port", None),
                                       log_file=self.run_dir / "viewer.log")
            grpc_url = self.viewer.grpc_url
            if self.viewer.web_url:
                print(f"live view: {self.viewer.web_url}", flush=True)
            else:
                print(f"live view: Rerun viewer window (listening on {grpc_url})", flush=True)
        try:
            self.view = open_flight_recording(self.mission, self.run_dir, grpc_url=grpc_url)
        except BaseException:
            self._close_viewer()
            raise
        log.info("recording to %s", self.run_dir / RECORDING_FILE)
        return self

    @property
    def sink(self) -> Any:
        """The app's telemetry sink (``on_tick(est, cmd, app)``)."""
        return self.view

    def stats(self) -> dict[str, Any]:
        """For the report: the recording's file and size, rows, drops, the logging thread's CPU time."""
        return self._stats or (self.view.stats() if self.view is not None else {})

    def __exit__(self, *exc: object) -> None:
        from companion.viz.flight import RECORDING_FILE

        try:
            if self.view is not None:
                self.view.recorder.close()
                path = self.run_dir / RECORDING_FILE
                written = path.stat().st_size if path.exists() else 0
                if written:
                    from companion.viz.viewer import optimize_recording

                    optimize_recording(path)
                self._stats = {"file": str(path), "bytes": path.stat().st_size if path.exists() else 0,
                               "bytes_written": written, **self.view.stats()}
                if self._stats.get("dropped"):
                    log.warning("recording: %d ticks dropped (the logging thread fell behind)",
                                self._stats["dropped"])
        finally:
            self._close_viewer()

    def _close_viewer(self) -> None:
        if self.viewer is not None:
            self.viewer.close()
            self.viewer = None


def flight_view(args: argparse.Namespace, mission: Any, run_dir: Path) -> FlightViewSession | None:
    """The session for ``fly`` (None with ``--no-recording``); ``--view`` with ``--no-recording`` is an error."""
    if getattr(args, "no_recording", False):
        if getattr(args, "view", None):
            raise ConfigError("--view needs the recording: drop --no-recording")
        return None
    return FlightViewSession(args, mission, run_dir)


# -- replay ------------------------------------------------------------------------------------------------
def add_replay_parser(subparsers: Any) -> argparse.ArgumentParser:
    """``replay RUN_DIR``: open a flight's recording."""
    p = subparsers.add_parser(
        "replay", help="open a run folder's recording.rrd in Rerun's viewer",
        description="Open RUN_DIR/recording.rrd (or an .rrd file) in Rerun's viewer: the native window when there "
        "is a display, else Rerun's web viewer served on 127.0.0.1 (the URL is printed; Ctrl-C stops it).",
    )
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a run folder from `slungpilot fly`, or an .rrd file")
    how = p.add_mutually_exclusive_group()
    how.add_argument("--web", action="store_true", help="serve the web viewer even when a display exists")
    how.add_argument("--native", action="store_true", help="open the native viewer window")
    p.add_argument("--port", type=int, default=None, help="web viewer port (default 9090, else a free port)")
    p.set_defaults(func=run_replay)
    return p


def recording_path(run_dir: Path) -> Path:
    """``run_dir/recording.rrd`` (or ``run_dir`` itself when it is an .rrd file); ConfigError when missing."""
    from companion.viz.flight import RECORDING_FILE

    path = run_dir if run_dir.suffix == ".rrd" else run_dir / RECORDING_FILE
    if not path.is_file():
        raise ConfigError(f"{path}: no recording here (flights write one unless --no-recording was given)")
    return path


def run_replay(args: argparse.Namespace) -> int:
    """Open the recording; with the web viewer, serve until Ctrl-C or SIGTERM (the viewer is stopped with us)."""
    from companion.proclife import sigterm_as_interrupt
    from companion.viz.viewer import start_viewer

    path = recording_path(args.run_dir)
    mode = "web" if args.web else "native" if args.native else "auto"
    with sigterm_as_interrupt():  # from before the viewer starts: a SIGTERM at any moment stops it cleanly
        viewer = start_viewer(mode, web_port=args.port, files=[path.resolve()])
        if not viewer.web_url:
            print(f"replay of {path} in the Rerun viewer window", flush=True)
            return 0
        try:
            print(f"replay of {path}: {viewer.web_url}  (Ctrl-C to stop)", flush=True)
            code = viewer.wait()
        except KeyboardInterrupt:  # between the start and the wait
            viewer.close()
            code = 130
    return 0 if code in (0, 130, -15) else 1


# -- view: every vehicle on the Zenoh network --------------------------------------------------------------
def add_view_parser(subparsers: Any) -> argparse.ArgumentParser:
    """``view``: every vehicle on the Zenoh network, live."""
    from companion.zenoh_io.session import add_zenoh_arguments

    p = subparsers.add_parser(
        "view", help="show every vehicle on the Zenoh network live in Rerun's viewer",
        description="Subscribe to <prefix>/*/state|swing|setpoint|obstacles|status and draw every vehicle under "
        "its own path (world/<id>/..., plots/<id>/...) on the wall-clock timeline. Connects to "
        "tcp/127.0.0.1:7447 like `listen`. Native window when there is a display, else the web viewer on "
        "127.0.0.1 (URL printed). Ctrl-C stops.",
    )
    how = p.add_mutually_exclusive_group()
    how.add_argument("--web", action="store_true", help="serve the web viewer even when a display exists")
    how.add_argument("--native", action="store_true", help="open the native viewer window")
    p.add_argument("--port", type=int, default=None, help="web viewer port (default 9090, else a free port)")
    p.add_argument("--save", type=Path, default=None, metavar="FILE", help="also write the recording to FILE.rrd")
    p.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0: until Ctrl-C)")
    p.add_argument("--headless", action="store_true", help="no viewer at all (with --save: record only)")
    add_zenoh_arguments(p, "listener")
    p.set_defaults(func=run_view)
    return p


def run_view(args: argparse.Namespace) -> int:
    """Subscribe and draw until Ctrl-C, SIGTERM or ``--duration`` (the web viewer is stopped either way)."""
    from companion.proclife import sigterm_as_interrupt
    from companion.viz.fleet import run_fleet_view

    with sigterm_as_interrupt():
        return run_fleet_view(args, lambda line: print(line, flush=True))
