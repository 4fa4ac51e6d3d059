"""Gymnasium environments; importing this package registers ``IGDrivSim/Driving-v0``."""

from igdrivsim.envs.driving import (
    ENV_ID,
    DrivingEnv,
    DrivingFunctions,
    EnvState,
    driving_functions,
    register,
)

__all__ = ["ENV_ID", "DrivingEnv", "DrivingFunctions", "EnvState", "driving_functions",
           "register"]
