"""State estimation: vehicle state from telemetry, the swing estimate (pure)."""

#: What ``--swing-input`` may say (see :mod:`companion.estimation.swing_feed`).
SWING_INPUTS = ("auto", "cable_sensor", "estimate", "estimate_imu", "estimate_fixes", "payload_position", "none")
