"""Batched simulators of a spec's system (ode/map, the MuJoCo swimmer, user factories)."""

from .simulators import (CheckedSimulator, OdeSimulator, SimulatorError, build_simulator, register_simulator,
                         registered_simulators)

__all__ = ["CheckedSimulator", "OdeSimulator", "SimulatorError", "build_simulator", "register_simulator",
           "registered_simulators"]
