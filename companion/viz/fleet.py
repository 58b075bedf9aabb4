"""``slungpilot view``: every vehicle on the Zenoh network in one live 3-D view, each under its own path.

Subscribes to ``<prefix>/*/state|swing|setpoint|obstacles|status`` and the liveliness tokens
``<prefix>/*/alive`` (schemas in ``docs/zenoh.md``). Zenoh's callbacks only copy the key and the bytes into the
:class:`~companion.viz.recorder.Recorder`'s bounded queue; the logging thread decodes and draws:

* ``world/<id>/uav`` (pose from ``state``), ``world/<id>/payload`` and ``world/<id>/cable`` (the state's payload
  position), ``world/<id>/envelope`` (R_max from ``swing`` around the last position), ``world/<id>/reference``
  (``setpoint``), ``world/<id>/path/flown/<k>`` (10 Hz), ``world/<id>/trunks/mission|live`` (``obstacles``, live
  ones labelled with their source);
* ``plots/<id>/swing`` (α, β rad), ``plots/<id>/envelope`` (m), ``plots/<id>/attitude`` (deg),
  ``plots/<id>/thrust`` (N); ``log/<id>`` narrates phase and outcome changes, joins and leaves.

Timelines: ``wall_time`` (the publisher's ``wall_s``, common to every vehicle) and ``vehicle_time`` (``t_s``).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from companion.core.obstacles import Obstacle
from companion.core.vehicle_params import VehicleParams
from companion.errors import ConfigError
from companion.viz import scene
from companion.viz.flight import log_trunks
from companion.viz.recorder import Recorder

log = logging.getLogger(__name__)

STREAMS = ("state", "swing", "setpoint", "obstacles", "status")
PATH_DT_S = 0.1
PATH_SEGMENT = 100


def fleet_blueprint() -> rrb.Blueprint:
    """3-D scene of all vehicles, their swing and attitude, the event log; time panel on wall time."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="fleet (NED, altitude up)"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="plots", contents="plots/*/swing", name="swing α, β (rad)"),
                rrb.TimeSeriesView(origin="plots", contents="plots/*/attitude", name="attitude (deg)"),
                rrb.TimeSeriesView(origin="plots", contents="plots/*/thrust", name="thrust (N)"),
                rrb.TimeSeriesView(origin="plots", contents="plots/*/envelope", name="envelope R_max (m)"),
                rrb.TextLogView(origin="log", name="events"),
            ),
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline="wall_time", state="collapsed"),
    )


def _f(x: Any) -> float:
    return math.nan if x is None else float(x)


def _vec(v: Any, n: int = 3) -> list[float]:
    return [math.nan] * n if not isinstance(v, list) or len(v) != n else [_f(x) for x in v]


class _Vehicle:
    def __init__(self) -> None:
        self.pos: list[float] | None = None
        self.r_max = math.nan
        self.cable_l: float | None = None
        self.path: list[list[float]] = []
        self.segment = 0
        self.next_path_t = -math.inf
        self.status: tuple | None = None
        self.obstacles: list | None = None
        self.samples = 0


class FleetScene:
    """The logging thread's handler: raw Zenoh samples ``(kind, key, bytes)`` → per-vehicle entities."""

    def __init__(self, prefix: str = "slungpilot") -> None:
        self.prefix = prefix
        self.vehicles: dict[str, _Vehicle] = {}
        self.bad_samples = 0
        self._airframe = scene.airframe_strips(VehicleParams().r_uav, VehicleParams().L_uav)

    def _vehicle(self, rec: rr.RecordingStream, vid: str) -> _Vehicle:
        v = self.vehicles.get(vid)
        if v is None:
            v = self.vehicles[vid] = _Vehicle()
            w = f"world/{vid}"
            rec.log(f"{w}/{scene.AIRFRAME}", rr.LineStrips3D(self._airframe, colors=[scene.RGB_AIRFRAME],
                                                             radii=rr.Radius.ui_points(1.5)), static=True)
            rec.log(f"{w}/{scene.UAV}", rr.Points3D([[0.0, 0.0, 0.0]], radii=[0.001], labels=[f"vehicle {vid}"],
                                                    show_labels=True), static=True)
            rec.log(f"{w}/{scene.PAYLOAD}", rr.Points3D.from_fields(colors=[scene.RGB_PAYLOAD], radii=[0.08]),
                    static=True)
            rec.log(f"{w}/{scene.CABLE}", rr.LineStrips3D.from_fields(colors=[(90, 90, 90)],
                                                                      radii=rr.Radius.ui_points(1.5)), static=True)
            rec.log(f"{w}/{scene.REFERENCE}", rr.Points3D.from_fields(colors=[scene.RGB_REFERENCE], radii=[0.05]),
                    static=True)
            p = f"plots/{vid}"
            rec.log(f"{p}/swing", rr.SeriesLines(names=[f"{vid} α", f"{vid} β"]), static=True)
            rec.log(f"{p}/attitude", rr.SeriesLines(names=[f"{vid} roll", f"{vid} pitch", f"{vid} yaw"]), static=True)
            rec.log(f"{p}/thrust", rr.SeriesLines(names=[f"{vid} thrust (N)"]), static=True)
            rec.log(f"{p}/envelope", rr.SeriesLines(names=[f"{vid} R_max (m)"]), static=True)
        return v

    def __call__(self, rec: rr.RecordingStream, items: list[Any]) -> None:
        groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
        for kind, key, raw, t_rx in items:
            parts = key.split("/")
            if len(parts) < 2:
                continue
            vid, stream = parts[-2], parts[-1]
            if kind == "alive":
                rec.set_time("wall_time", timestamp=t_rx)
                self._vehicle(rec, vid)
                rec.log(f"log/{vid}", rr.TextLog(f"vehicle {vid} {'joined' if raw else 'left'}", level="INFO"))
                continue
            try:
                d = json.loads(raw)
                if not isinstance(d, dict) or not isinstance(d.get("wall_s"), int | float):
                    raise ValueError("not a slungpilot sample")
            except ValueError:
                self.bad_samples += 1
                continue
            groups[(vid, stream)].append(d)
        for (vid, stream), samples in groups.items():
            v = self._vehicle(rec, vid)
            v.samples += len(samples)
            getattr(self, f"_{stream}")(rec, vid, v, samples)

    @staticmethod
    def _times(samples: list[dict]) -> list[rr.TimeColumn]:
        wall = np.array([float(s["wall_s"]) for s in samples])
        t = np.array([_f(s.get("t_s")) for s in samples])
        return [rr.TimeColumn("wall_time", timestamp=wall), rr.TimeColumn("vehicle_time", duration=np.nan_to_num(t))]

    def _set_time(self, rec: rr.RecordingStream, s: dict) -> None:
        rec.set_time("wall_time", timestamp=float(s["wall_s"]))
        rec.set_time("vehicle_time", duration=_f(s.get("t_s")) if s.get("t_s") is not None else 0.0)

    def _state(self, rec: rr.RecordingStream, vid: str, v: _Vehicle, samples: list[dict]) -> None:
        w = f"world/{vid}"
        pos = np.array([_vec(s.get("pos_ned_m")) for s in samples])
        eul = np.array([_vec(s.get("euler_rad")) for s in samples])
        ok = np.all(np.isfinite(pos), axis=1) & np.all(np.isfinite(eul), axis=1)
        if not ok.any():
            return
        samples = [s for s, k in zip(samples, ok, strict=True) if k]
        pos, eul = pos[ok], eul[ok]
        times = self._times(samples)
        rec.send_columns(f"{w}/{scene.UAV}", times, rr.Transform3D.columns(
            translation=pos, quaternion=scene.quat_xyzw_from_euler(eul)))
        n = len(samples)
        rec.send_columns(f"plots/{vid}/attitude", times,
                         rr.Scalars.columns(scalars=np.degrees(eul).ravel()).partition([3] * n))
        v.pos = pos[-1].tolist()
        if np.isfinite(v.r_max):
            scale = np.tile([v.r_max, v.r_max, 1.0], (n, 1))
            rec.send_columns(f"{w}/{scene.ENVELOPE}", times, rr.Transform3D.columns(translation=pos, scale=scale))
        pay = np.array([_vec(s.get("payload_pos_ned_m")) for s in samples])
        okp = np.all(np.isfinite(pay), axis=1)
        if okp.any():
            tp = self._times([s for s, k in zip(samples, okp, strict=True) if k])
            ones = [1] * int(okp.sum())
            rec.send_columns(f"{w}/{scene.PAYLOAD}", tp, rr.Points3D.columns(positions=pay[okp]).partition(ones))
            strips = [np.stack([a, b]) for a, b in zip(pos[okp], pay[okp], strict=True)]
            rec.send_columns(f"{w}/{scene.CABLE}", tp, rr.LineStrips3D.columns(strips=strips).partition(ones))
            if v.cable_l is None:
                v.cable_l = float(np.linalg.norm(pay[okp][0] - pos[okp][0]))
                rec.log(f"{w}/{scene.ENVELOPE_SHAPE}", rr.LineStrips3D(
                    scene.envelope_strips(v.cable_l), colors=[(*scene.RGB_ENVELOPE, 160)],
                    radii=rr.Radius.ui_points(1.0)), static=True)
        for s, p in zip(samples, pos, strict=True):
            t = _f(s.get("t_s"))
            if not t >= v.next_path_t:
                continue
            v.next_path_t = t + PATH_DT_S
            v.path.append(p.tolist())
            if len(v.path) >= 2:
                self._set_time(rec, s)
                rec.log(f"{w}/{scene.PATHS}/flown/{v.segment:04d}", rr.LineStrips3D(
                    [v.path], colors=[scene.RGB_UAV], radii=rr.Radius.ui_points(2.0)))
            if len(v.path) >= PATH_SEGMENT:
                v.segment += 1
                v.path = [v.path[-1]]

    def _swing(self, rec: rr.RecordingStream, vid: str, v: _Vehicle, samples: list[dict]) -> None:
        times = self._times(samples)
        ab = np.array([[_f(s.get("alpha_rad")), _f(s.get("beta_rad"))] for s in samples])
        rec.send_columns(f"plots/{vid}/swing", times, rr.Scalars.columns(scalars=ab.ravel()).partition([2] * len(ab)))
        r = np.array([_f(s.get("r_max_m")) for s in samples])
        rec.send_columns(f"plots/{vid}/envelope", times, rr.Scalars.columns(scalars=r))
        fin = r[np.isfinite(r)]
        if fin.size:
            v.r_max = float(fin[-1])

    def _setpoint(self, rec: rr.RecordingStream, vid: str, v: _Vehicle, samples: list[dict]) -> None:
        ref = np.array([_vec(s.get("ref_pos_ned_m")) for s in samples])
        ok = np.all(np.isfinite(ref), axis=1)
        if ok.any():
            rec.send_columns(f"world/{vid}/{scene.REFERENCE}", self._times([s for s, k in zip(samples, ok, strict=True)
                                                                             if k]),
                             rr.Points3D.columns(positions=ref[ok]).partition([1] * int(ok.sum())))
        thrust = np.array([_f(s.get("thrust_n")) for s in samples])
        rec.send_columns(f"plots/{vid}/thrust", self._times(samples), rr.Scalars.columns(scalars=thrust))

    def _obstacles(self, rec: rr.RecordingStream, vid: str, v: _Vehicle, samples: list[dict]) -> None:
        s = samples[-1]  # the set in use now; the stream repeats it at least once a second
        if s.get("obstacles") == v.obstacles:
            return
        v.obstacles = s.get("obstacles")
        obs: list[Obstacle] = []
        for o in s.get("obstacles") or []:
            try:
                obs.append(Obstacle(float(o["x_m"]), float(o["y_m"]), float(o["radius_m"]),
                                    float(o.get("height_m", 4.0)), float(o.get("safe_distance_m", 0.1)),
                                    source=str(o.get("source", "?"))))
            except (KeyError, TypeError, ValueError):
                self.bad_samples += 1
        self._set_time(rec, s)
        mission = [o for o in obs if o.source == "mission"]
        live = [o for o in obs if o.source != "mission"]
        log_trunks(rec, f"world/{vid}/{scene.TRUNKS}/mission", mission, scene.RGB_TRUNK_MISSION)
        log_trunks(rec, f"world/{vid}/{scene.TRUNKS}/live", live, scene.RGB_TRUNK_LIVE)

    def _status(self, rec: rr.RecordingStream, vid: str, v: _Vehicle, samples: list[dict]) -> None:
        for s in samples:
            key = (s.get("phase"), s.get("outcome"), s.get("mode"), s.get("armed"))
            if key != v.status:
                v.status = key
                self._set_time(rec, s)
                rec.log(f"log/{vid}", rr.TextLog(f"vehicle {vid}: phase {key[0]}, outcome {key[1]}, mode {key[2]}, "
                                                 f"armed {key[3]}", level="INFO"))


def run_fleet_view(args: argparse.Namespace, say: Callable[[str], None]) -> int:
    """Subscribe and draw until Ctrl-C or ``args.duration``; ``say`` gets the viewer's URL and a last line."""
    from companion.viz.viewer import start_viewer
    from companion.zenoh_io.session import DEFAULT_PREFIX, open_session, zenoh_config_from_args

    prefix = getattr(args, "zenoh_prefix", DEFAULT_PREFIX)
    if args.headless and not args.save:
        raise ConfigError("--headless: nothing to do without --save FILE")
    cfg = zenoh_config_from_args(args, "listener")
    handler = FleetScene(prefix)
    sinks: list[Any] = []
    viewer = None
    if args.save:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(args.save)))
    try:
        if not args.headless:
            viewer = start_viewer("web" if args.web else "native" if args.native else "auto", web_port=args.port)
            sinks.append(rr.GrpcSink(viewer.grpc_url))
            say(f"fleet view: {viewer.web_url or 'Rerun viewer window'}  (Ctrl-C to stop)")
        recorder = Recorder("slungpilot-fleet", handler, sinks, blueprint=fleet_blueprint(),
                            setup=lambda rec: rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_DOWN, static=True))

        def on_sample(s: Any) -> None:  # Zenoh thread: copy out and queue, never block
            recorder.put(("sample", str(s.key_expr), s.payload.to_bytes(), time.time()))

        def on_alive(s: Any) -> None:
            recorder.put(("alive", str(s.key_expr), s.kind == _put_kind(), time.time()))

        t_end = time.monotonic() + args.duration if args.duration > 0 else math.inf
        with open_session(cfg) as session, recorder:
            subs = [session.declare_subscriber(f"{prefix}/*/{st}", on_sample) for st in STREAMS]
            subs.append(session.liveliness().declare_subscriber(f"{prefix}/*/alive", on_alive, history=True))
            saving = f"; recording to {args.save}" if args.save else ""
            say(f"subscribed to {prefix}/*/{{{','.join(STREAMS)}}}{saving}")
            try:
                while time.monotonic() < t_end:
                    time.sleep(0.1)
            except KeyboardInterrupt:
                pass
            for sub in subs:
                sub.undeclare()
    finally:
        if viewer is not None:
            viewer.close()
    seen = ", ".join(f"{vid} ({v.samples} samples)" for vid, v in sorted(handler.vehicles.items())) or "none"
    say(f"vehicles seen: {seen}; dropped {recorder.dropped}, undecodable {handler.bad_samples}")
    return 0


def _put_kind() -> Any:
    import zenoh

    return zenoh.SampleKind.PUT
