"""The task a layout grades, as a value: ``Task`` and the constants its kinds share.

``layout/task.py`` resolves it from the layout (the structured field, else the sentence that
``layout/sentence.py`` reads); this module stands alone so both can build it.
"""

from __future__ import annotations

from dataclasses import dataclass

KINDS = ("pick", "place", "move")
RELATIONS = ("in", "on")
DIRECTIONS = ("left", "right", "forward", "backward")
# relation[TASK_FIELD]: the structured task (a dict); relation["task"] is EmbodiedGen's free
# task category ("pick and place"), kept as written and never graded (LEGACY_FIELD: a dict
# there is still read as the structured task, as before the field moved)
TASK_FIELD = "task_spec"
LEGACY_FIELD = "task"
TASK_KEYS = ("kind", "objects", "receptacle", "relation", "direction")
# a move's direction in the robot base's frame (forward: away from the robot), and how far the
# expert and the reward take a mover along it (success needs envs/tasks/move.py's MIN_SHIFT);
# placement keeps that destination on the table and within reach
DIRECTION_XY = {"forward": (1.0, 0.0), "backward": (-1.0, 0.0), "left": (0.0, 1.0),
                "right": (0.0, -1.0)}  # fmt: skip
MOVE_SHIFT = 0.15  # m
# the most movers a task may name: the state observation's mover slots (envs/observation.py's
# MAX_MOVERS, the same number); a layout naming more is refused at load, so `layout validate` too
MAX_MOVERS = 3
EXAMPLE = '{"kind": "place", "objects": ["pen"], "receptacle": "mug", "relation": "in"}'
EXPLICIT = f'or state it in relation["{TASK_FIELD}"], e.g. {EXAMPLE}'


@dataclass(frozen=True)
class Task:
    """One env's task: ``kind`` (pick, place, move), ``objects`` (the movers' node names, in
    the order the expert takes them), ``receptacle`` (a node name, for place), ``relation``
    ("in" or "on", for place), ``direction`` (left, right, forward, backward, for move)."""

    kind: str
    objects: tuple[str, ...]
    receptacle: str | None = None
    relation: str | None = None
    direction: str | None = None

    def as_dict(self) -> dict:
        return {
            "kind": self.kind, "objects": list(self.objects), "receptacle": self.receptacle,
            "relation": self.relation, "direction": self.direction,
        }  # fmt: skip

    def spec(self) -> dict:
        """The structured form (``relation[TASK_FIELD]``): ``as_dict`` without empty keys."""
        return {k: v for k, v in self.as_dict().items() if v is not None}

    def shift(self) -> tuple[float, float] | None:
        """A move's destination relative to each mover's start, in the robot base's frame
        (``MOVE_SHIFT`` along the direction); None for other kinds."""
        if self.kind != "move":
            return None
        x, y = DIRECTION_XY[self.direction]
        return x * MOVE_SHIFT, y * MOVE_SHIFT

    def describe(self) -> str:
        """One line, as ``layout validate`` prints it."""
        objects = ", ".join(self.objects)
        if self.kind == "place":
            return f"place [{objects}] {self.relation} {self.receptacle}"
        if self.kind == "move":
            return f"move [{objects}] {self.direction}"
        return f"pick [{objects}]"

    def sentence(self, names: dict[str, str]) -> str:
        """The task in words, from each node's description in ``names``."""
        what = " and ".join(names.get(n, n) for n in self.objects)
        if self.kind == "place":
            return f"Put {what} {self.relation} {names.get(self.receptacle, self.receptacle)}."
        if self.kind == "move":
            way = self.direction if self.direction in ("forward", "backward") else "to the"
            return f"Move {what} {way}{'' if way == self.direction else ' ' + self.direction}."
        return f"Pick up {what} and hold it at the goal."
