"""State estimation: vehicle state from telemetry, the swing estimate (pure)."""

#: What ``--swing-input`` may say: the cable sensor, else the payload's position, else none (``auto``), or one.
SWING_INPUTS = ("auto", "cable_sensor", "payload_position", "none")
