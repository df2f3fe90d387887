"""Scripted policies."""

from embodied_envs.solvers.pick_place import EnvReport, PickPlaceSolver, SolveResult
from embodied_envs.solvers.solver_config import SolverConfig

__all__ = ["EnvReport", "PickPlaceSolver", "SolveResult", "SolverConfig"]
