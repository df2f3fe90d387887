"""The state observation's task part: every mover and the receptacle, in a fixed layout.

Every env of every layout set observes the same keys and shapes (one observation shape over a
mixed set of pick, place and move layouts): ``MAX_MOVERS`` mover slots, a slot an env's task
does not fill (fewer movers) zero, with a per-slot mask; the receptacle's slot zero, masked,
where the task has none (pick, move, a place on the table). docs/tasks.md, "Observations".
"""

from __future__ import annotations

import numpy as np
import torch

from embodied_envs.envs import fast_reads
from embodied_envs.envs.tasks import KIND_IDS
from embodied_envs.envs.tasks.scene import TaskReader, TaskScene, quat_matrix
from embodied_envs.envs.tasks.state import concat
from embodied_envs.layout import LayoutError

MAX_MOVERS = 3  # mover slots of the state observation; a layout whose task moves more is refused
POSE, POS, GEOMETRY = 7, 3, 6  # a slot's raw pose, a vector, the receptacle's geometry
# the state modes' task keys, in their order (``extras``), each ``(n, width)``
STATE_KEYS = {
    "mover_pose": MAX_MOVERS * POSE,
    "tcp_to_mover_pos": MAX_MOVERS * POS,
    "mover_to_goal_pos": MAX_MOVERS * POS,
    "mover_mask": MAX_MOVERS,
    "receptacle_pose": POSE,
    "receptacle_geometry": GEOMETRY,
    "receptacle_mask": 1,
}


def check_movers(layouts) -> None:
    """Refuses, naming the file, a layout whose task moves more than ``MAX_MOVERS`` objects."""
    for layout in layouts:
        objects = layout.task.objects
        if len(objects) > MAX_MOVERS:
            raise LayoutError(
                f"{layout.source}: its task moves {len(objects)} objects {list(objects)}; the "
                f"env observes at most MAX_MOVERS={MAX_MOVERS} (envs/observation.py). Fix: name "
                f'at most {MAX_MOVERS} in relation["task_spec"]["objects"].'
            )


class StateObservation:
    """Reads the state observation's task keys (:data:`STATE_KEYS`) of one configuration's
    envs: numpy arrays from SAPIEN on the CPU simulation's one env, tensors on the GPU's batch
    (as :class:`TaskReader` reads), returned as float32 tensors on the env's device."""

    def __init__(self, scene: TaskScene, reader: TaskReader, device: torch.device):
        self.ts, self.reader, self.device = scene, reader, device
        counts = np.array([len(t.objects) for t in scene.tasks])
        m = len(scene.movers)  # the configuration's slots: its most movers (TaskScene)
        mask = (np.arange(MAX_MOVERS) < counts[:, None]).astype(np.float32)  # (n, MAX_MOVERS)
        has_rec = (~scene.rec_is_table)[:, None].astype(np.float32)  # (n, 1)
        pick = (scene.kinds.numpy() == KIND_IDS["pick"])[:, None, None]  # (n, 1, 1)
        arr, n = reader.arr, len(counts)
        self.live = arr(mask[:, :m, None])  # (n, m, 1): the configuration's slots an env fills
        # the slots past the configuration's, zero: (n, MAX_MOVERS - m, width) per width
        self.pads = {w: arr(np.zeros((n, MAX_MOVERS - m, w), np.float32)) for w in (POSE, POS)}
        self.is_pick, self.centres = arr(pick.astype(np.float32)), reader.centres
        self.all_pick = bool(pick.all())  # no destination to read: the centres unneeded
        self.rec_mask = arr(has_rec)
        self.fixed = {  # what stays the same over a configuration, as the observation holds it
            "mover_mask": torch.as_tensor(mask, device=device),
            "receptacle_geometry": torch.as_tensor(scene.rec_geometry * has_rec, device=device),
            "receptacle_mask": torch.as_tensor(has_rec, device=device),
        }

    def _poses(self):
        """``(n, m + 1, 7)``: the movers' raw poses, then the receptacle's."""
        actors = [*self.ts.movers, self.ts.receptacle]
        if self.reader.gpu:
            return torch.stack([a.pose.raw_pose for a in actors], 1)
        return fast_reads.raw_poses(actors)

    def _slots(self, x):
        """``x (n, m, d)`` with the slots no env's task fills zero, padded to ``MAX_MOVERS``
        slots, flat: ``(n, MAX_MOVERS * d)``."""
        return concat([x * self.live, self.pads[x.shape[-1]]], 1).reshape(x.shape[0], -1)

    def extras(self, tcp_pos) -> dict:
        """The task keys now (:data:`STATE_KEYS`, in order); ``tcp_pos (n, 3)`` the TCP.

        Per mover slot: its raw pose (origin, scalar-first quaternion); ``tcp_to_mover_pos``
        its origin less the TCP; ``mover_to_goal_pos`` what its task's success measures: the
        goal less its origin (``pick``), its destination less its centre (``place``,
        ``move``; ``TaskState.dest``)."""
        poses = self._poses()
        m = poses.shape[1] - 1
        movers, rec = poses[:, :m], poses[:, m]
        tcp = tcp_pos if self.reader.gpu else tcp_pos.cpu().numpy()
        origin = movers[..., :3]
        to_goal = self.reader.goal()[:, None] - origin  # the pick goal
        if not self.all_pick:
            centre = origin + (quat_matrix(movers[..., 3:]) @ self.centres[..., None])[..., 0]
            to_goal = to_goal * self.is_pick + (self.reader.dest - centre) * (1 - self.is_pick)
        fixed = {k: v.clone() for k, v in self.fixed.items()}  # the caller's to change
        out = {
            "mover_pose": self._slots(movers),
            "tcp_to_mover_pos": self._slots(origin - tcp[:, None]),
            "mover_to_goal_pos": self._slots(to_goal),
            "mover_mask": fixed["mover_mask"],
            "receptacle_pose": rec * self.rec_mask,
            "receptacle_geometry": fixed["receptacle_geometry"],
            "receptacle_mask": fixed["receptacle_mask"],
        }
        return {k: torch.as_tensor(v, device=self.device) for k, v in out.items()}
