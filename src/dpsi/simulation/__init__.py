"""Differentiable MLS-MPM simulation of an elastoplastic object pressed by a rigid effector."""

from .config import Scene, SimulatorConfig, SimulationError
from .mpm import Simulator

__all__ = ["Scene", "SimulatorConfig", "SimulationError", "Simulator"]
