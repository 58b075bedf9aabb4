"""Controllers by name (``smc_ff``, ``smc``, ``pid``), attitude/thrust from force, and their gains."""

from companion.control.attitude import attitude_from_force, limit_force, limit_force_xyz
from companion.control.params import ControllerConfig, load_controller_config
from companion.control.position import (
    PositionController,
    PositionOutput,
    SwingAccelEstimator,
    feedforward_acc,
    feedforward_xyz,
    make_position_controller,
    payload_reaction_n,
)

CONTROLLER_NAMES = ("smc_ff", "smc", "pid")

__all__ = [
    "CONTROLLER_NAMES",
    "ControllerConfig",
    "PositionController",
    "PositionOutput",
    "SwingAccelEstimator",
    "attitude_from_force",
    "feedforward_acc",
    "feedforward_xyz",
    "limit_force",
    "limit_force_xyz",
    "load_controller_config",
    "make_position_controller",
    "payload_reaction_n",
]
