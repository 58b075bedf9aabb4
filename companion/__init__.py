"""slungpilot's companion application.

Subpackages, one concern each (data flows telemetry → estimate → plan → control → setpoint):

* ``core``: the quadrotor–payload model, swing envelope, wind, rotations, obstacles, missions (pure);
* ``estimation``: vehicle state from telemetry, swing estimation (pure);
* ``planning``, ``control``: planners and controllers (pure);
* ``autopilots``: what PX4, ArduPilot and the bundled vehicle mean by modes, thrust and readiness (pure tables);
* ``flight``: the pilot (pure: the flight sequence, its failsafes, the per-tick flight core) and its two thin
  runners (real time on asyncio; lockstep, a blocking loop);
* ``launch``: the typed flight run (``FlySpec``) and ``fly_mission``, the bundled vehicle's launcher;
* ``mavlink_io``, ``zenoh_io``: thin I/O shells (MAVLink over UDP and its typed telemetry, Zenoh streams);
* ``report``: flight logs, metrics, the run folder and its plots;
* ``cli``: the ``slungpilot`` command line (flags → ``FlySpec``) and benchmarks.

``config`` (the project's ``config/`` folder) ships as the package ``companion.configs``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("slungpilot")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"
