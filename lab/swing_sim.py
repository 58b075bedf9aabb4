"""What real autopilots would send, simulated from the bundled physics, and the swing estimator fed with it.

:class:`SensorSuite` turns the true state at each control tick into time-stamped messages, each with the time its
data is valid and the time it arrives at the companion:

* ATTITUDE (default 100 Hz): Euler angles and body rates with a seeded white noise and a constant bias
  (the autopilot's own estimate is not the truth);
* HIGHRES_IMU (default 50 Hz, PX4's onboard-link rate): the accelerometer's specific force in body FRD, an
  average over one control period (the IMU's delta-velocity integration), with the noise and bias model of
  :class:`ImuNoise` (presets: PX4 SITL's Gazebo IMU plugin, PX4 SIH);
* LOCAL_POSITION_NED (50 Hz): airframe position and velocity with white noise;
* payload fixes (10 Hz, ArduPilot's slung-payload convention: the payload position relative to the vehicle's):
  white noise, a latency with jitter (so fixes can arrive out of sequence), random dropouts and one long gap.

:class:`EstimatorDriver` owns a :class:`~companion.estimation.swing_estimator.SwingEstimator`, starts it at
lift-off, feeds it what has arrived by each tick and returns its estimate. The same driver runs offline (over a
recorded :class:`TruthLog`) and in the loop (``lab.inprocess.fly_inprocess(swing_source="estimate")``).
Deterministic: every random draw comes from one ``numpy.random.Generator`` seeded by the caller.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field, replace

import numpy as np

from companion.core.model import rotation_body_to_ned
from companion.core.vehicle_params import VehicleParams
from companion.estimation.swing_config import SwingEstimate, SwingEstimatorConfig
from companion.estimation.swing_estimator import SwingEstimator

G_E = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class ImuNoise:
    """Accelerometer error model (per axis, body FRD).

    ``white_mps2``: white noise per sample at the IMU's internal rate ``rate_hz`` (3 values, m/s²);
    ``turn_on_bias_mps2``: 1σ of the constant bias drawn at start; ``bias_walk_mps2_sqrt_s``: random walk of the
    bias (m/s²/√s) with first-order decay ``bias_tau_s``.
    """

    name: str = "px4_gazebo"
    white_mps2: tuple[float, float, float] = (0.0294, 0.0294, 0.0294)
    rate_hz: float = 250.0
    turn_on_bias_mps2: float = 0.196
    bias_walk_mps2_sqrt_s: float = 0.006
    bias_tau_s: float = 300.0

    @staticmethod
    def px4_gazebo() -> ImuNoise:
        """PX4 SITL's Gazebo IMU plugin (iris.sdf): accelerometer noise density 0.00186 m/s²/√Hz (0.0294 m/s²
        per sample at 250 Hz), random walk 0.006 m/s³/√Hz, correlation time 300 s, turn-on bias 0.196 m/s²."""
        return ImuNoise()

    @staticmethod
    def px4_sih() -> ImuNoise:
        """PX4 SIH (sih.cpp, armed): white noise 0.5, 1.7, 1.4 m/s² per sample (x, y, z), no bias."""
        return ImuNoise("px4_sih", (0.5, 1.7, 1.4), 250.0, 0.0, 0.0, 300.0)

    def scaled(self, k: float) -> ImuNoise:
        """Every noise and bias term multiplied by ``k``."""
        return replace(self, name=f"{self.name}x{k:g}", white_mps2=tuple(k * v for v in self.white_mps2),
                       turn_on_bias_mps2=k * self.turn_on_bias_mps2,
                       bias_walk_mps2_sqrt_s=k * self.bias_walk_mps2_sqrt_s)


@dataclass(frozen=True)
class SensorConfig:
    """Rates (Hz), noise (1σ) and timing of the simulated messages; see the module docstring."""

    imu: ImuNoise = field(default_factory=ImuNoise)
    imu_hz: float = 50.0
    imu_latency_s: float = 0.002
    attitude_hz: float = 100.0
    attitude_white_rad: float = 0.002
    attitude_bias_rad: float = 0.003
    rates_white_rad_s: float = 0.01
    vel_hz: float = 50.0
    vel_white_mps: float = 0.02
    pos_white_m: float = 0.01
    fix_hz: float = 10.0
    fix_white_m: float = 0.02
    fix_latency_s: float = 0.10
    fix_jitter_s: float = 0.10
    fix_dropout: float = 0.15
    fix_gap_s: tuple[float, float] | None = (9.0, 11.5)
    use_imu: bool = True
    use_fixes: bool = True
    use_velocity: bool = True


@dataclass(frozen=True, slots=True)
class TruthSample:
    """One control tick: time (s), full model state x (16,), the thrust commanded for the next period (N),
    the average specific force over the period that ended at ``t_s`` (NED, m/s²), airborne flag, and the
    collective thrust the rotors produced in the last physics step (N; differs from the command when a rotor
    saturates)."""

    t_s: float
    x: np.ndarray
    thrust_cmd_n: float
    specific_force_ned_mps2: np.ndarray
    airborne: bool
    thrust_actual_n: float = math.nan


@dataclass
class TruthLog:
    """A recorded flight: :class:`TruthSample` rows and the vehicle parameters."""

    params: VehicleParams
    samples: list[TruthSample] = field(default_factory=list)


class TruthRecorder:
    """Builds :class:`TruthSample` rows from a stepping :class:`~sim_bridge.physics.VehicleSim`: call
    :meth:`sample` at each tick with the state *before* the command for that tick, then :meth:`commanded`."""

    def __init__(self) -> None:
        self._prev: tuple[float, np.ndarray] | None = None

    def sample(self, sim) -> TruthSample:
        x = sim.x.copy()
        t = float(sim.t_s)
        if self._prev is None or t <= self._prev[0]:
            f = -sim.params.g * G_E  # at rest (the first tick is on the ground)
        else:
            t0, x0 = self._prev
            f = (x[8:11] - x0[8:11]) / (t - t0) - sim.params.g * G_E
        self._prev = (t, x)
        # 'airborne' for the estimator: the payload hangs on a taut cable (while it rests on the ground the cable
        # is slack and its angles are no swing; the companion skips those too)
        return TruthSample(t, x, math.nan, f, not sim.landed and not sim.payload_on_ground, sim.thrust_n)

    @staticmethod
    def commanded(s: TruthSample, thrust_n: float) -> TruthSample:
        return replace(s, thrust_cmd_n=float(thrust_n))


# ----------------------------------------------------------------------------------------------------- sensors
@dataclass(order=True)
class Message:
    """A message as the companion receives it: arrival time, order, validity time, kind, data."""

    t_arrive: float
    seq: int
    t_valid: float = field(compare=False)
    kind: str = field(compare=False)
    data: tuple = field(compare=False)


class SensorSuite:
    """Simulated autopilot and payload messages from :class:`TruthSample` rows (see module docstring)."""

    def __init__(self, params: VehicleParams, cfg: SensorConfig | None = None, seed: int = 0) -> None:
        self.params = params
        self.cfg = cfg or SensorConfig()
        self.rng = np.random.default_rng(seed)
        c = self.cfg
        self._bias = self.rng.normal(0.0, c.imu.turn_on_bias_mps2, 3) if c.imu.turn_on_bias_mps2 > 0 else np.zeros(3)
        self._att_bias = np.array([*self.rng.normal(0.0, c.attitude_bias_rad, 2), 0.0])
        self._next = {"att": -1.0, "imu": -1.0, "vel": -1.0, "fix": -1.0}
        self._pending: list[Message] = []
        self._seq = 0
        self._t_prev: float | None = None
        self.fixes_sent = 0
        self.fixes_dropped = 0

    def _due(self, key: str, t: float, hz: float) -> bool:
        if hz <= 0.0:
            return False
        if self._next[key] < 0.0:
            self._next[key] = t
        if t + 1e-9 >= self._next[key]:
            self._next[key] += 1.0 / hz
            if self._next[key] <= t:  # never fall behind by more than one period
                self._next[key] = t + 1.0 / hz
            return True
        return False

    def _push(self, t_arrive: float, t_valid: float, kind: str, data: tuple) -> None:
        heapq.heappush(self._pending, Message(t_arrive, self._seq, t_valid, kind, data))
        self._seq += 1

    def observe(self, s: TruthSample) -> None:
        """Generate the messages whose sample time is this tick."""
        c = self.cfg
        rng = self.rng
        t = s.t_s
        x = s.x
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        # the IMU bias wanders every tick
        if c.imu.bias_walk_mps2_sqrt_s > 0.0 and dt > 0.0:
            self._bias += -self._bias * dt / c.imu.bias_tau_s + rng.normal(0.0, c.imu.bias_walk_mps2_sqrt_s
                                                                           * math.sqrt(dt), 3)
        if self._due("att", t, c.attitude_hz):
            eul = x[3:6] + self._att_bias + rng.normal(0.0, c.attitude_white_rad, 3)
            phi, th = x[3], x[4]
            dphi, dth, dpsi = x[11:14]
            rates = np.array([dphi - math.sin(th) * dpsi,
                              math.cos(phi) * dth + math.sin(phi) * math.cos(th) * dpsi,
                              -math.sin(phi) * dth + math.cos(phi) * math.cos(th) * dpsi])
            rates = rates + rng.normal(0.0, c.rates_white_rad_s, 3)
            self._push(t, t, "att", (eul, rates))
        if self._due("imu", t, c.imu_hz) and c.use_imu and dt > 0.0:
            # the average over the last period, rotated into the body frame at the period's middle
            eul_mid = x[3:6] - 0.5 * dt * x[11:14]
            R = rotation_body_to_ned(*eul_mid)
            f_b = R.T @ s.specific_force_ned_mps2 + self._bias + rng.normal(0.0, 1.0, 3) * np.asarray(c.imu.white_mps2)
            self._push(t + c.imu_latency_s, t - 0.5 * dt, "imu", (f_b,))
        if self._due("vel", t, c.vel_hz) and c.use_velocity:
            v = x[8:11] + rng.normal(0.0, c.vel_white_mps, 3)
            p = x[0:3] + rng.normal(0.0, c.pos_white_m, 3)
            self._push(t, t, "vel", (v, p))
        if self._due("fix", t, c.fix_hz) and c.use_fixes:
            lost = rng.random() < c.fix_dropout
            if c.fix_gap_s is not None and c.fix_gap_s[0] <= t < c.fix_gap_s[1]:
                lost = True
            lat = c.fix_latency_s + c.fix_jitter_s * rng.random()
            noise = rng.normal(0.0, c.fix_white_m, 3)
            if lost:
                self.fixes_dropped += 1
            else:
                al, be = x[6], x[7]
                l = self.params.l
                r = l * np.array([math.sin(al) * math.cos(be), -math.sin(be), math.cos(al) * math.cos(be)])
                self._push(t + lat, t, "fix", (r + noise,))
                self.fixes_sent += 1

    def arrived(self, t: float) -> list[Message]:
        """Messages that have arrived by ``t``, in arrival order."""
        out = []
        while self._pending and self._pending[0].t_arrive <= t + 1e-12:
            out.append(heapq.heappop(self._pending))
        return out


# ---------------------------------------------------------------------------------------------------- driver
def estimator_config_for(sensors: SensorConfig, **overrides) -> SwingEstimatorConfig:
    """The estimator told the noise of the sensors it gets, as a user would configure it: the IMU's white noise
    per axis (at least 0.035 m/s²: the model's own mismatch), the fixes' and the velocity's white noise."""
    cfg = SwingEstimatorConfig(
        imu_sigma_mps2=tuple(max(0.035, float(w)) for w in sensors.imu.white_mps2),
        fix_sigma_m=max(0.01, sensors.fix_white_m), vel_sigma_mps=max(0.01, sensors.vel_white_mps))
    return replace(cfg, **overrides)


class EstimatorDriver:
    """A :class:`SwingEstimator` started at lift-off and fed with a :class:`SensorSuite`'s messages.

    ``model_params``: what the companion believes about vehicle and payload (default: the truth's parameters).
    """

    def __init__(self, params: VehicleParams, sensors: SensorConfig | None = None, seed: int = 0,
                 est_config: SwingEstimatorConfig | None = None, model_params: VehicleParams | None = None) -> None:
        self.suite = SensorSuite(params, sensors, seed)
        self.model_params = model_params or params
        self.est_config = est_config or estimator_config_for(self.suite.cfg)
        self.est: SwingEstimator | None = None
        self.cpu_s = 0.0
        self.tick_cpu_s: list[float] = []  # estimator CPU per control tick (process time, s)
        self.updates = 0
        self._last_thrust: tuple[float, float] | None = None
        self._last_att: Message | None = None
        #: per tick after lift-off: (t, estimated [α, β, α̇, β̇], true [α, β, α̇, β̇], sigma_rad, fade)
        self.history: list[tuple[float, np.ndarray, np.ndarray, float, float]] = []

    def step(self, s: TruthSample) -> SwingEstimate | None:
        """Observe tick ``s`` and return the estimate at ``s.t_s`` (None before lift-off)."""
        import time

        self.suite.observe(s)
        msgs = self.suite.arrived(s.t_s)
        if self.est is None:
            for msg in msgs:
                if msg.kind == "att":
                    self._last_att = msg
            if not s.airborne:
                return None
            self.est = SwingEstimator(self.model_params, self.est_config, t0_s=s.t_s, swing0=s.x[[6, 7, 14, 15]],
                                      vel0_ned_mps=s.x[8:11])
            if self._last_thrust is not None:
                self.est.set_thrust(self._last_thrust[0], self._last_thrust[1])
            if self._last_att is not None:
                self.est.set_attitude_euler(self._last_att.t_valid, *self._last_att.data)
        est = self.est
        c0 = time.process_time()
        for msg in msgs:
            if msg.t_valid < est._base.t - 1.0:
                continue
            if msg.kind == "att":
                est.set_attitude_euler(msg.t_valid, msg.data[0], msg.data[1])
            elif msg.kind == "imu":
                est.update_imu(msg.t_valid, msg.data[0])
                self.updates += 1
            elif msg.kind == "vel":
                est.update_velocity(msg.t_valid, msg.data[0], msg.data[1])
                self.updates += 1
            elif msg.kind == "fix":
                est.update_payload_offset(msg.t_valid, msg.data[0])
                self.updates += 1
        out = est.estimate(s.t_s)
        dt_cpu = time.process_time() - c0
        self.cpu_s += dt_cpu
        self.tick_cpu_s.append(dt_cpu)
        self.history.append((s.t_s, out.swing, s.x[[6, 7, 14, 15]], out.sigma_rad, out.fade))
        return out

    def command(self, t_s: float, thrust_n: float) -> None:
        """The thrust commanded at ``t_s`` (applied from then on)."""
        self._last_thrust = (t_s, thrust_n)
        if self.est is not None:
            self.est.set_thrust(t_s, thrust_n)
