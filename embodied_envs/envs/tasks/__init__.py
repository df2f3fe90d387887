"""The task kinds' rules: one small file per kind (``pick``, ``place``, ``move``), each with
``evaluate(state)`` (the success flags) and ``reward(state, info)`` (the staged dense reward,
up to its ``MAX_REWARD``), written once for numpy arrays (the CPU simulation's one env) and
torch tensors (the GPU's batch). What they read is :class:`TaskState`; ``TaskReader``
(``tasks/scene.py``) reads it from the simulation and applies the rules. Where the reward is,
where success is: here.
"""

from embodied_envs.envs.tasks import move, pick, place
from embodied_envs.envs.tasks.state import TaskState

RULES = {"pick": pick, "place": place, "move": move}  # kind -> its rules module
KIND_IDS = {kind: k for k, kind in enumerate(RULES)}  # kind -> its index in observations
INFO_KEYS = ("is_grasped", "is_obj_placed", "is_robot_static", "obj_to_goal_pos")

__all__ = ["INFO_KEYS", "KIND_IDS", "RULES", "TaskState"]
