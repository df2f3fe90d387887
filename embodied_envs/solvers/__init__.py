"""Scripted policies."""

from embodied_envs.solvers.pick_place import EnvReport, PickPlaceSolver, SolverConfig, SolveResult

__all__ = ["EnvReport", "PickPlaceSolver", "SolveResult", "SolverConfig"]
