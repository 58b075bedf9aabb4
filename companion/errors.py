"""The project's small exception hierarchy.

Every error a user can cause (bad file, bad flag, unreachable autopilot) is one of these, carries a
message that names what is wrong and where, and maps to a CLI exit code.
"""


class SlungpilotError(Exception):
    """Base class of every error slungpilot raises on purpose."""

    exit_code = 1


class ConfigError(SlungpilotError):
    """A configuration or mission file (or a flag) is missing, malformed or non-physical."""

    exit_code = 2


class LinkError(SlungpilotError):
    """The MAVLink or Zenoh link failed: no heartbeat, a refused command, a closed socket."""

    exit_code = 3


class ModelError(SlungpilotError, ValueError):
    """Non-finite or out-of-domain numbers reached the dynamics model."""

    exit_code = 4
