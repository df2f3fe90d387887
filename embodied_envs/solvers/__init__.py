"""Scripted policies."""

from embodied_envs.solvers.pick_place import EnvReport, PickPlaceSolver, SolveResult, SolverConfig

__all__ = ["EnvReport", "PickPlaceSolver", "SolveResult", "SolverConfig"]
