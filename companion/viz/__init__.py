"""The live 3-D view and its recordings, on Rerun's SDK (an I/O shell; nothing here is on the control path).

* :mod:`companion.viz.scene` — pure geometry and entity names: airframe, envelope cylinder, trunks, colours.
* :mod:`companion.viz.recorder` — one Rerun recording fed from a bounded queue by a logging thread that batches
  rows into columns (the control loop only appends a tuple; a full queue drops and counts).
* :mod:`companion.viz.flight` — the flight's telemetry sink (``on_tick(est, cmd, app)``) and what it draws.
* :mod:`companion.viz.fleet` — ``slungpilot view``: every vehicle on the Zenoh network, each under its own path.
* :mod:`companion.viz.viewer` — starting Rerun viewers: native window, or the web viewer on a loopback port.
"""
