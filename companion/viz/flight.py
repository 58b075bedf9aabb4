"""The flight's 3-D view and recording: a telemetry sink (``on_tick(est, cmd, app)``) and what it draws.

Per control tick the sink appends one tuple of floats to the :class:`~companion.viz.recorder.Recorder`'s queue
(≈ 2 µs); nothing is logged before the mission starts (the first tick with a command), and the timeline
``mission_time`` counts simulated seconds from that tick (``vehicle_time``, the autopilot's boot time, is kept
as a second timeline). The logging thread then writes, per batch:

* every tick (sent twice a second) — ``plots/swing`` (α, β rad), ``plots/attitude`` (roll, pitch, yaw and
  commanded roll, pitch, deg), ``plots/thrust`` (N), ``plots/thrust_norm`` (0..1), ``plots/envelope`` (R_max, m);
* at ``view_hz`` of mission time (default 30 Hz) — ``world/uav`` (pose; ``world/uav/airframe`` is the static
  X and rotors), ``world/envelope`` (the R_max cylinder around the vehicle down to the cable's length),
  ``world/payload``, ``world/cable``, ``world/reference`` (the planner's reference point);
* at ``path_hz`` (default 10 Hz) — the flown, payload and reference paths as line strips in segments of
  ``PATH_SEGMENT`` points (``world/path/<flown|payload|reference>/<k>``), so each row stays short;
* on change (checked 5 times a second) — ``world/trunks/mission`` (static), ``world/trunks/live`` (labelled with
  their Zenoh source), ``world/trunks/gone`` (live trunks whose publisher withdrew them or let them expire);
  ``log/events`` narrates the mission start, phase changes and trunks arriving and leaving.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from companion.core.mission import Mission
from companion.core.obstacles import Obstacle
from companion.viz import scene
from companion.viz.recorder import Recorder

log = logging.getLogger(__name__)

RECORDING_FILE = "recording.rrd"
APPLICATION_ID = "slungpilot"
PATH_SEGMENT = 100
OBSTACLE_CHECK_S = 0.2
SCALARS_EVERY_S = 0.5  # wall time between time-series sends
NAN = math.nan
_NO_CMD = (NAN, NAN, NAN, NAN, NAN, NAN, NAN, NAN)
_NAN3 = (NAN, NAN, NAN)

# Row layout (floats first, then strings), as built by FlightView.on_tick.
T_M, T_V, POS, EUL, ALPHA, BETA, ROLL_CMD, PITCH_CMD, THRUST_N, THRUST_NORM, R_MAX, REF, PAY = (
    0, 1, slice(2, 5), slice(5, 8), 8, 9, 10, 11, 12, 13, 14, slice(15, 18), slice(18, 21))
N_FLOATS = 21


def flight_blueprint(prefix: str = "") -> rrb.Blueprint:
    """The layout: the 3-D scene on the left; swing, attitude, thrust and the event log on the right;
    the time panel on ``mission_time``."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin=f"{prefix}world", name="flight (NED, altitude up)"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin=f"{prefix}plots/swing", name="swing α, β (rad)"),
                rrb.TimeSeriesView(origin=f"{prefix}plots/attitude", name="attitude (deg)"),
                rrb.TimeSeriesView(origin=f"{prefix}plots/thrust", name="thrust (N)"),
                rrb.TimeSeriesView(origin=f"{prefix}plots/envelope", name="envelope R_max (m)"),
                rrb.TextLogView(origin=f"{prefix}log", name="events"),
            ),
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline="mission_time", state="collapsed"),
    )


def log_static_scene(rec: rr.RecordingStream, mission: Mission, prefix: str = "") -> None:
    """World axes, airframe, the unit envelope cylinder, start and goal, the mission's trunks, series names."""
    w = f"{prefix}world"
    vp = mission.vehicle
    rec.log(w, rr.ViewCoordinates.RIGHT_HAND_Z_DOWN, static=True)
    rec.log(f"{w}/{scene.AIRFRAME}", rr.LineStrips3D(scene.airframe_strips(vp.r_uav, vp.L_uav),
                                                     colors=[scene.RGB_AIRFRAME], radii=rr.Radius.ui_points(1.5)),
            static=True)
    rec.log(f"{w}/{scene.ENVELOPE_SHAPE}", rr.LineStrips3D(scene.envelope_strips(vp.l),
                                                           colors=[(*scene.RGB_ENVELOPE, 160)],
                                                           radii=rr.Radius.ui_points(1.0)), static=True)
    rec.log(f"{w}/{scene.MISSION}/start", rr.Points3D([mission.start_ned_m], colors=[scene.RGB_START], radii=0.12,
                                                      labels=["start"]), static=True)
    rec.log(f"{w}/{scene.MISSION}/goal", rr.Points3D([mission.goal_ned_m], colors=[scene.RGB_GOAL], radii=0.15,
                                                     labels=["goal"]), static=True)
    log_trunks(rec, f"{w}/{scene.TRUNKS}/mission", list(mission.obstacles), scene.RGB_TRUNK_MISSION, static=True)
    rec.log(f"{w}/{scene.PAYLOAD}", rr.Points3D.from_fields(colors=[scene.RGB_PAYLOAD], radii=[0.08]), static=True)
    rec.log(f"{w}/{scene.CABLE}", rr.LineStrips3D.from_fields(colors=[(90, 90, 90)], radii=rr.Radius.ui_points(1.5)),
            static=True)
    rec.log(f"{w}/{scene.REFERENCE}", rr.Points3D.from_fields(colors=[scene.RGB_REFERENCE], radii=[0.05]),
            static=True)
    log_series_names(rec, prefix)


def log_series_names(rec: rr.RecordingStream, prefix: str = "") -> None:
    """Names and colours of the time series."""
    p = f"{prefix}plots"
    rec.log(f"{p}/swing", rr.SeriesLines(names=["α", "β"], colors=[(31, 119, 180), (214, 39, 40)]), static=True)
    rec.log(f"{p}/attitude", rr.SeriesLines(
        names=["roll φ", "pitch θ", "yaw ψ", "roll cmd", "pitch cmd"],
        colors=[(31, 119, 180), (255, 127, 14), (44, 160, 44), (140, 190, 230), (255, 200, 140)]), static=True)
    rec.log(f"{p}/thrust", rr.SeriesLines(names=["thrust (N)"], colors=[(148, 103, 189)]), static=True)
    rec.log(f"{p}/thrust_norm", rr.SeriesLines(names=["thrust (0..1)"], colors=[(148, 103, 189)]), static=True)
    rec.log(f"{p}/envelope", rr.SeriesLines(names=["R_max (m)"], colors=[(23, 190, 207)]), static=True)


def log_trunks(rec: rr.RecordingStream, path: str, obstacles: Sequence[Obstacle], rgb: tuple[int, int, int],
               *, static: bool = False) -> None:
    """Trunks as solid cylinders labelled with their source, and their safe-distance radius as a wire frame
    (``<path>/safe``); an empty list clears the path."""
    if not obstacles:
        rec.log(path, rr.Clear(recursive=True), static=static)
        return
    t = scene.trunk_arrays(obstacles)
    rec.log(path, rr.Cylinders3D(lengths=t.lengths, radii=t.radii, centers=t.centers, colors=[rgb],
                                 fill_mode="solid", labels=t.labels, show_labels=False), static=static)
    rec.log(f"{path}/safe", rr.Cylinders3D(lengths=t.lengths, radii=t.safe_radii, centers=t.centers,
                                           colors=[(*rgb, 90)], fill_mode="majorwireframe"), static=static)


def _time_columns(t_m: np.ndarray, t_v: np.ndarray) -> list[rr.TimeColumn]:
    return [rr.TimeColumn("mission_time", duration=t_m), rr.TimeColumn("vehicle_time", duration=t_v)]


def _scalar_columns(values: np.ndarray) -> Any:
    n, k = values.shape
    return rr.Scalars.columns(scalars=values.ravel()).partition([k] * n)


class FlightScene:
    """The logging thread's handler: tick rows and events → column sends (see the module docstring)."""

    def __init__(self, mission: Mission, *, view_hz: float = 30.0, path_hz: float = 10.0, prefix: str = "") -> None:
        self.mission = mission
        self.l_m = mission.vehicle.l
        self.r2_m = mission.vehicle.r_uav + mission.vehicle.L_uav
        self.view_dt = 1.0 / view_hz
        self.path_dt = 1.0 / path_hz
        self.w = f"{prefix}world"
        self.p = f"{prefix}plots"
        self.log_path = f"{prefix}log/events"
        self._next_view = -math.inf
        self._next_path = -math.inf
        self._paths: dict[str, list[list[float]]] = {"flown": [], "payload": [], "reference": []}
        self._segment: dict[str, int] = dict.fromkeys(self._paths, 0)
        self._phase: tuple[str, str] | None = None
        self._live: set[tuple] = set()
        self.rows_3d = 0
        self.rows = 0
        self._scalars: list[np.ndarray] = []  # tick rows waiting for the next scalar send
        self._scalars_sent_wall = time.monotonic()

    def __call__(self, rec: rr.RecordingStream, items: list[Any]) -> None:
        rows: list[tuple] = []
        for it in items:
            if isinstance(it[0], str):
                if rows:
                    self._rows(rec, rows)
                    rows = []
                self._event(rec, it)
            else:
                rows.append(it)
        if rows:
            self._rows(rec, rows)

    # -- events ------------------------------------------------------------------------------------------
    def _event(self, rec: rr.RecordingStream, it: tuple) -> None:
        kind, t_m, t_v = it[0], it[1], it[2]
        rec.set_time("mission_time", duration=t_m)
        rec.set_time("vehicle_time", duration=t_v)
        if kind == "obstacles":
            seen, current = it[3], it[4]
            _, live, gone = scene.split_trunks(seen, current)
            log_trunks(rec, f"{self.w}/{scene.TRUNKS}/live", live, scene.RGB_TRUNK_LIVE)
            log_trunks(rec, f"{self.w}/{scene.TRUNKS}/gone", gone, scene.RGB_TRUNK_GONE)
            now = {(o.x_m, o.y_m, o.radius_m, o.source) for o in live}
            for o in sorted(now - self._live):
                rec.log(self.log_path, rr.TextLog(f"live trunk from {o[3]}: x {o[0]:.2f} m, y {o[1]:.2f} m, "
                                                  f"radius {o[2]:.2f} m", level="INFO"))
            for o in sorted(self._live - now):
                rec.log(self.log_path, rr.TextLog(f"live trunk from {o[3]} gone: x {o[0]:.2f} m, y {o[1]:.2f} m",
                                                  level="INFO"))
            self._live = now
        elif kind == "text":
            rec.log(self.log_path, rr.TextLog(it[3], level=it[4] if len(it) > 4 else "INFO"))

    # -- tick rows -----------------------------------------------------------------------------------------
    def _rows(self, rec: rr.RecordingStream, rows: list[tuple]) -> None:
        a = np.array([r[:N_FLOATS] for r in rows], dtype=np.float64)
        self.rows += len(rows)
        t_m = a[:, T_M]
        for r in rows:
            phase = (r[N_FLOATS], r[N_FLOATS + 1])
            if phase != self._phase:
                self._phase = phase
                rec.set_time("mission_time", duration=r[T_M])
                rec.set_time("vehicle_time", duration=r[T_V])
                rec.log(self.log_path, rr.TextLog(f"phase {phase[0]}" + (f" / {phase[1]}" if phase[1] else "")))
        r_max = self._r_max(a)
        # Every send costs a fixed ~0.5 ms in the SDK whatever its length, so the plots go out twice a second
        # (the 3-D scene every batch, for a smooth live view).
        self._scalars.append(np.column_stack([a, r_max]))
        if time.monotonic() - self._scalars_sent_wall >= SCALARS_EVERY_S:
            self.finish(rec)
        # 3-D at view_hz and paths at path_hz of mission time
        pick, ppick = [], []
        for i, t in enumerate(t_m):
            if t >= self._next_view:
                pick.append(i)
                nxt = self._next_view + self.view_dt  # phase-locked, unless the rows jumped ahead
                self._next_view = nxt if nxt > t else t + self.view_dt
            if t >= self._next_path:
                ppick.append(i)
                self._next_path = t + self.path_dt
        if pick:
            self._frames(rec, a[pick], r_max[pick])
        if ppick:
            self._path_rows(rec, a[ppick])

    def finish(self, rec: rr.RecordingStream) -> None:
        """Send the buffered tick rows as the time series (also called once when the recording closes)."""
        self._scalars_sent_wall = time.monotonic()
        if not self._scalars:
            return
        a = np.concatenate(self._scalars)
        self._scalars = []
        times = _time_columns(a[:, T_M], a[:, T_V])
        p = self.p
        rec.send_columns(f"{p}/swing", times, _scalar_columns(a[:, [ALPHA, BETA]]))
        att = np.degrees(np.column_stack([a[:, EUL], a[:, [ROLL_CMD, PITCH_CMD]]]))
        rec.send_columns(f"{p}/attitude", times, _scalar_columns(att))
        rec.send_columns(f"{p}/thrust", times, rr.Scalars.columns(scalars=a[:, THRUST_N]))
        rec.send_columns(f"{p}/thrust_norm", times, rr.Scalars.columns(scalars=a[:, THRUST_NORM]))
        rec.send_columns(f"{p}/envelope", times, rr.Scalars.columns(scalars=a[:, N_FLOATS]))

    def _r_max(self, a: np.ndarray) -> np.ndarray:
        """R_max as the planner used it; from the swing angles (eq. 21) on ticks without a command (landing),
        the full cable when the swing is unknown too."""
        r = a[:, R_MAX].copy()
        miss = ~np.isfinite(r)
        if miss.any():
            al, be = a[miss, ALPHA], a[miss, BETA]
            r1 = self.l_m * np.sqrt((np.cos(be) * np.sin(al)) ** 2 + np.sin(be) ** 2)
            r[miss] = np.where(np.isfinite(r1), np.maximum(r1, self.r2_m), max(self.l_m, self.r2_m))
        return r

    def _payload(self, a: np.ndarray) -> np.ndarray:
        pay = scene.payload_pos_ned_m(a[:, POS], a[:, ALPHA], a[:, BETA], self.l_m)
        raw = ~np.all(np.isfinite(pay), axis=1)
        pay[raw] = a[raw, PAY]  # no swing angles: the payload's own position stream, when there is one
        return pay

    def _frames(self, rec: rr.RecordingStream, a: np.ndarray, r_max: np.ndarray) -> None:
        self.rows_3d += len(a)
        w = self.w
        times = _time_columns(a[:, T_M], a[:, T_V])
        pos = a[:, POS]
        rec.send_columns(f"{w}/{scene.UAV}", times, rr.Transform3D.columns(
            translation=pos, quaternion=scene.quat_xyzw_from_euler(a[:, EUL])))
        scale = np.column_stack([r_max, r_max, np.ones(len(a))])
        rec.send_columns(f"{w}/{scene.ENVELOPE}", times, rr.Transform3D.columns(translation=pos, scale=scale))
        pay = self._payload(a)
        ok = np.all(np.isfinite(pay), axis=1)
        if ok.any():
            tp = _time_columns(a[ok, T_M], a[ok, T_V])
            ones = [1] * int(ok.sum())
            rec.send_columns(f"{w}/{scene.PAYLOAD}", tp, rr.Points3D.columns(positions=pay[ok]).partition(ones))
            strips = [np.stack([p, q]) for p, q in zip(pos[ok], pay[ok], strict=True)]
            rec.send_columns(f"{w}/{scene.CABLE}", tp, rr.LineStrips3D.columns(strips=strips).partition(ones))
        ref = a[:, REF]
        okr = np.all(np.isfinite(ref), axis=1)
        if okr.any():
            rec.send_columns(f"{w}/{scene.REFERENCE}", _time_columns(a[okr, T_M], a[okr, T_V]),
                             rr.Points3D.columns(positions=ref[okr]).partition([1] * int(okr.sum())))

    def _path_rows(self, rec: rr.RecordingStream, a: np.ndarray) -> None:
        pay = self._payload(a)
        for name, pts, rgb in (("flown", a[:, POS], scene.RGB_UAV), ("payload", pay, scene.RGB_PAYLOAD),
                               ("reference", a[:, REF], scene.RGB_REFERENCE)):
            for i in range(len(a)):
                p = pts[i]
                if not np.all(np.isfinite(p)):
                    continue
                seg = self._paths[name]
                seg.append(p.tolist())
                path = f"{self.w}/{scene.PATHS}/{name}/{self._segment[name]:04d}"
                rec.set_time("mission_time", duration=a[i, T_M])
                rec.set_time("vehicle_time", duration=a[i, T_V])
                if len(seg) == 2:  # a new segment: its colour and width once
                    rec.log(path, rr.LineStrips3D.from_fields(colors=[rgb], radii=rr.Radius.ui_points(
                        1.0 if name == "reference" else 2.0)), static=True)
                if len(seg) >= 2:
                    rec.log(path, rr.LineStrips3D.from_fields(strips=[seg]))
                if len(seg) >= PATH_SEGMENT:
                    self._segment[name] += 1
                    self._paths[name] = [seg[-1]]


class FlightView:
    """The flight's telemetry sink: ``on_tick(est, cmd, app)`` queues one row per tick for the recording.

    ``current_obstacles()`` (optional) returns the obstacle set the planner uses now (the Zenoh store's
    ``last_obstacles``), so the view can tell live trunks from expired ones; without it every non-mission
    trunk in ``app.obstacles_seen`` is drawn as live.
    """

    def __init__(self, recorder: Recorder, scene_handler: FlightScene,
                 current_obstacles: Callable[[], Sequence[Obstacle] | None] | None = None) -> None:
        self.recorder = recorder
        self.scene = scene_handler
        self.current_obstacles = current_obstacles
        self.t0_s: float | None = None
        self._next_obs = -math.inf
        self._seen: tuple[Obstacle, ...] | None = None
        self._current: tuple[Obstacle, ...] | None = None
        self.ticks = 0

    def on_transition(self, t: Any, app: Any) -> None:
        """Nothing: the event log shows the flight's phases as the ticks carry them."""

    def on_tick(self, est: Any, cmd: Any, app: Any) -> None:
        """One row: times, position, attitude, swing, command (or NaN), raw payload position, phases."""
        if self.t0_s is None:
            if cmd is None:
                return
            self.t0_s = float(est.t_s)
            self.recorder.put(("text", 0.0, self.t0_s, f"mission start (vehicle time {self.t0_s:.3f} s)", "INFO"))
        t_v = float(est.t_s)
        t_m = t_v - self.t0_s
        sw = est.swing
        if sw is not None:
            alpha, beta, pay = float(sw[0]), float(sw[1]), _NAN3
        else:
            alpha = beta = NAN
            pp = getattr(getattr(app, "state", None), "payload_pos_ned_m", None)
            pay = _NAN3 if pp is None else tuple(pp.tolist())
        if cmd is not None:
            e, ref = cmd.euler_cmd_rad, cmd.ref_pos_ned_m
            c = (float(e[0]), float(e[1]), float(cmd.thrust_n), float(cmd.thrust_norm), float(cmd.r_max_m),
                 float(ref[0]), float(ref[1]), float(ref[2]))
            core_phase = cmd.phase
        else:
            c, core_phase = _NO_CMD, ""
        self.recorder.put((t_m, t_v, *est.pos_ned_m.tolist(), *est.euler_rad.tolist(), alpha, beta, *c, *pay,
                           str(getattr(app, "phase", "")), core_phase))
        self.ticks += 1
        if t_m >= self._next_obs:
            self._next_obs = t_m + OBSTACLE_CHECK_S
            self._check_obstacles(t_m, t_v, app)

    def _check_obstacles(self, t_m: float, t_v: float, app: Any) -> None:
        seen = tuple(getattr(app, "obstacles_seen", ()) or ())
        current = self.current_obstacles() if self.current_obstacles is not None else None
        current = tuple(current) if current is not None else None
        if seen != self._seen or current != self._current:
            self._seen, self._current = seen, current
            self.recorder.put(("obstacles", t_m, t_v, seen, current))

    def stats(self) -> dict[str, Any]:
        """Counters for the report: ticks queued, 3-D frames, the recorder's queue and thread numbers."""
        return {"ticks": self.ticks, "frames_3d": self.scene.rows_3d, **self.recorder.stats()}


def open_flight_recording(
    mission: Mission, run_dir: Path, *, grpc_url: str | None = None, view_hz: float = 30.0,
    recording_id: str | None = None,
) -> FlightView:
    """A started :class:`FlightView` writing ``run_dir/recording.rrd`` and, with ``grpc_url``, streaming to
    the viewer there (``rerun+http://127.0.0.1:PORT/proxy``). Close it with ``view.recorder.close()``."""
    handler = FlightScene(mission, view_hz=view_hz)
    sinks: list[Any] = [rr.FileSink(str(run_dir / RECORDING_FILE))]
    if grpc_url:
        sinks.append(rr.GrpcSink(grpc_url))
    recorder = Recorder(APPLICATION_ID, handler, sinks, blueprint=flight_blueprint(),
                        setup=lambda rec: log_static_scene(rec, mission), recording_id=recording_id)
    recorder.open()
    recorder.recording.send_recording_name(  # type: ignore[union-attr]
        f"{mission.name} {mission.planner} + {mission.controller}")
    return FlightView(recorder, handler)
