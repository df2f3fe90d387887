"""The layout's task, read from the layout: what is graded and what the expert does.

Resolution, in order:

1. ``relation["task"]``, a structured field (EmbodiedGen ignores it), wins::

       "task": {"kind": "place", "objects": ["pen"], "receptacle": "mug", "relation": "in"}
       "task": {"kind": "move", "objects": ["lamp"], "direction": "left"}
       "task": {"kind": "pick", "objects": ["can"]}

2. else ``relation["task_desc"]``, read by a small deterministic parser against the layout's
   node names (spaces, underscores and trailing digits ignored: "pen1" is a "pen"; "the pens"
   is every manipulated node of that stem) and ``objs_desc``:

   - **pick**: "Pick up X ...", "Lift X", "Grab X" (no destination);
   - **place**: "Put / Place / Set / Drop / Move X in / into / inside / on / onto / on top of
     B": among the destination phrases the receptacle is the first named object that is not
     the context ("Put the fruit on the table on the plate" -> the plate; "Place the pen in
     the mug on the desk" -> the mug); the context ("on the table") only when no other object
     is named;
   - **move**: "Move / Push / Slide / Shift X (to the) left / right / forward / backward", in
     the robot's frame (forward: away from the robot).

   The movers are the manipulated objects the object phrase names; where it names none (a
   description such as "the fruit"), every manipulated object that is not the receptacle.

3. else, no sentence at all: ``pick`` of the first manipulated object.

Anything else ("Close the laptop") is refused with one line that quotes the sentence.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from embodied_envs.layout.errors import LayoutError

KINDS = ("pick", "place", "move")
RELATIONS = ("in", "on")
DIRECTIONS = ("left", "right", "forward", "backward")
TASK_FIELD = "task"  # relation[TASK_FIELD]: the structured task
# a move's direction in the robot base's frame (forward: away from the robot), and how far the
# expert and the reward take a mover along it (success needs envs/tasks/move.py's MIN_SHIFT);
# placement keeps that destination on the table and within reach
DIRECTION_XY = {"forward": (1.0, 0.0), "backward": (-1.0, 0.0), "left": (0.0, 1.0),
                "right": (0.0, -1.0)}  # fmt: skip
MOVE_SHIFT = 0.15  # m

PICK_VERBS = ("pick", "lift", "grab", "grasp", "raise", "take")
PLACE_VERBS = ("put", "place", "set", "drop", "move", "transfer", "stack", "lay")
MOVE_VERBS = ("move", "push", "slide", "shift", "drag")
# destination prepositions (longest first) and the relation each states
PREPOSITIONS = (
    ("on top of", "on"), ("inside of", "in"), ("inside", "in"), ("into", "in"), ("onto", "on"),
    ("in", "in"), ("on", "on"),
)  # fmt: skip
DIRECTION_WORDS = {
    "left": "left", "right": "right", "forward": "forward", "forwards": "forward",
    "ahead": "forward", "away": "forward", "backward": "backward", "backwards": "backward",
    "back": "backward", "closer": "backward", "toward": "backward", "towards": "backward",
}  # fmt: skip
ARTICLES = {"the", "a", "an", "some", "all", "both", "two", "three", "of", "up", "it", "them"}
FORMS = (
    '"Pick up X", "Put/Place X in/on B", "Move X to the left/right/forward/backward"'
)
EXPLICIT = (
    f'or state it in relation["{TASK_FIELD}"], e.g. {{"kind": "place", "objects": ["pen"], '
    '"receptacle": "mug", "relation": "in"}'
)


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


def words(text: str) -> list[str]:
    """Lower-case words; apostrophes kept ("rubik's"), other punctuation dropped."""
    return re.findall(r"[a-z0-9']+", text.lower().replace("_", " "))


def stem(word: str) -> str:
    """A noun without a plural ending or trailing digits: pens, pen1 -> pen; boxes -> box."""
    word = re.sub(r"\d+$", "", word)
    for end, keep in (("ies", "y"), ("ches", "ch"), ("shes", "sh"), ("xes", "x"), ("ses", "s")):
        if word.endswith(end) and len(word) > len(end) + 1:
            return word[: -len(end)] + keep
    if word.endswith("s") and not word.endswith("ss") and len(word) > 3:
        return word[:-1]
    return word


def _stems(text: str) -> tuple[str, ...]:
    return tuple(s for s in (stem(w) for w in words(text)) if s)


def _names(node: str, desc: str | None) -> list[tuple[str, ...]]:
    """The word sequences (stemmed) that name ``node``: its name, and its description's last
    noun (the head of "a white bowl")."""
    out = [_stems(node)]
    if desc:
        head = _stems(desc.split(",")[0].split(" with ")[0])
        if head:
            out.append(head[-1:])
    return [n for n in out if n]


def _contains(phrase: tuple[str, ...], name: tuple[str, ...]) -> bool:
    n = len(name)
    return any(phrase[i : i + n] == name for i in range(len(phrase) - n + 1))


def _named(phrase: tuple[str, ...], nodes: list[str], desc: dict[str, str]) -> list[str]:
    """The nodes ``phrase`` names: by node name first; by description when no name matches."""
    by_name = [n for n in nodes if _contains(phrase, _names(n, None)[0])]
    if by_name:
        return by_name
    return [n for n in nodes if any(_contains(phrase, x) for x in _names(n, desc.get(n))[1:])]


def _refuse(f: str, sentence: str, why: str) -> LayoutError:
    return LayoutError(
        f'{f}: relation["task_desc"] "{sentence}" is not a task this env grades ({why}). '
        f"Understood: {FORMS}. Fix: rephrase it so, {EXPLICIT}."
    )


def _split_destinations(rest: list[str]) -> tuple[list[str], list[tuple[str, list[str]]]]:
    """The words before the first destination preposition, and each (relation, phrase)."""
    text = " " + " ".join(rest) + " "
    cuts = []
    for prep, rel in PREPOSITIONS:
        for m in re.finditer(f" {prep} ", text):
            if not any(a <= m.start() < b for a, b, _ in cuts):
                cuts.append((m.start(), m.end() - 1, rel))
    cuts.sort()
    if not cuts:
        return rest, []
    head = text[: cuts[0][0]].split()
    dests = []
    for k, (_, end, rel) in enumerate(cuts):
        stop = cuts[k + 1][0] if k + 1 < len(cuts) else len(text)
        dests.append((rel, text[end:stop].split()))
    return head, dests


def parse_task(sentence: str, layout, f: str) -> Task:
    """The task ``sentence`` states, against ``layout``'s nodes (see the module docstring).

    Raises:
        LayoutError: the sentence states no task this env grades, or names no object of it.
    """
    manipulated = list(layout.relation["manipulated_objs"])
    context = layout.relation["context"]
    nodes = [n for n in layout.objs_mapping if layout.objs_mapping[n] != "background"]
    desc = dict(layout.objs_desc or {})
    ws = [w for w in words(sentence) if w != "please"]
    if not ws:
        raise _refuse(f, sentence, "it is empty")
    verb, rest = ws[0], ws[1:]
    if verb in PICK_VERBS and "and" in rest:  # "pick up the pen and put it in the mug"
        k = rest.index("and")
        if k + 1 < len(rest) and rest[k + 1] in PLACE_VERBS:
            head, dests = rest[:k], _split_destinations(rest[k + 2 :])[1]
            verb = rest[k + 1]
        else:
            head, dests = _split_destinations(rest)
    else:
        head, dests = _split_destinations(rest)
    named = [
        (node, rel)
        for rel, phrase in dests
        for node in _named(_stems(" ".join(phrase)), nodes, desc)
    ]
    receptacle = next(((n, r) for n, r in named if n != context), None)
    direction = next((DIRECTION_WORDS[w] for w in reversed(ws) if w in DIRECTION_WORDS), None)

    def movers(exclude: str | None) -> tuple[str, ...]:
        phrase = _stems(" ".join(w for w in head if w not in DIRECTION_WORDS))
        found = [n for n in _named(phrase, manipulated, desc) if n != exclude]
        return tuple(found or [n for n in manipulated if n != exclude])

    if verb in MOVE_VERBS and direction is not None and receptacle is None:
        return Task("move", movers(None)[:1], direction=direction)
    if verb in PLACE_VERBS and dests:
        if not named:
            raise _refuse(f, sentence, "its destination names no object of the layout")
        node, relation = receptacle or named[0]  # the context only when nothing else is named
        objects = movers(node)
        if not objects:
            raise _refuse(f, sentence, "it names nothing to move but the receptacle")
        return Task("place", objects, node, relation)
    if verb in MOVE_VERBS:
        raise _refuse(f, sentence, "it names no direction and no destination")
    if verb in PICK_VERBS:  # "pick up the pen on the desk": a locative, not a destination
        found = _named(_stems(" ".join(head)), manipulated, desc)
        return Task("pick", (found[0] if found else manipulated[0],))
    raise _refuse(f, sentence, f'"{verb}" is not a verb it knows')


def _structured(spec, layout, f: str) -> Task:
    field = f'relation["{TASK_FIELD}"]'
    if not isinstance(spec, dict):
        raise LayoutError(f"{f}: {field} must be an object (dict). Fix: {EXPLICIT[3:]}.")
    kind = spec.get("kind")
    if kind not in KINDS:
        raise LayoutError(f'{f}: {field}["kind"] is {kind!r}, expected one of {list(KINDS)}.')
    objects = spec.get("objects", list(layout.relation["manipulated_objs"][:1]))
    if isinstance(objects, str):
        objects = [objects]
    nodes = [n for n in layout.objs_mapping if layout.objs_mapping[n] != "background"]
    if not objects or not all(o in layout.relation["manipulated_objs"] for o in objects):
        raise LayoutError(
            f'{f}: {field}["objects"] is {objects!r}: each must be a node of '
            f'relation["manipulated_objs"] {layout.relation["manipulated_objs"]}. Fix: name them.'
        )
    if kind == "pick" and len(objects) != 1:
        raise LayoutError(f'{f}: {field}: a pick task takes one object, got {objects}.')
    receptacle = relation = direction = None
    if kind == "place":
        receptacle, relation = spec.get("receptacle"), spec.get("relation", "on")
        if receptacle not in nodes or receptacle in objects:
            raise LayoutError(
                f'{f}: {field}["receptacle"] is {receptacle!r}: it must be an object node of the'
                f" layout other than the movers ({nodes}). Fix: name it."
            )
        if relation not in RELATIONS:
            raise LayoutError(f'{f}: {field}["relation"] is {relation!r}, expected "in" or "on".')
    if kind == "move":
        direction = spec.get("direction")
        if direction not in DIRECTIONS:
            raise LayoutError(
                f'{f}: {field}["direction"] is {direction!r}, expected one of {list(DIRECTIONS)}.'
            )
    return Task(kind, tuple(objects), receptacle, relation, direction)


def resolve_task(layout, f: str) -> Task:
    """``layout``'s task (a ``LayoutInfo`` or anything with its ``relation``, ``objs_mapping``,
    ``objs_desc`` and ``tree``), checked against the layout; ``f`` names the file in errors.

    Raises:
        LayoutError: a task that cannot be graded, or one already done as the file places it.
    """
    rel = layout.relation
    if TASK_FIELD in rel:
        task = _structured(rel[TASK_FIELD], layout, f)
    elif isinstance(rel.get("task_desc"), str) and rel["task_desc"].strip():
        task = parse_task(rel["task_desc"], layout, f)
    else:
        task = Task("pick", (rel["manipulated_objs"][0],))
    if task.kind == "place" and task.receptacle == rel["context"]:
        on_table = [n for n in task.objects if [n, "ON"] in [list(x) for x in
                    layout.tree.get(rel["context"], [])]]  # fmt: skip
        if on_table:
            raise LayoutError(
                f'{f}: the task puts {on_table} on the context "{rel["context"]}", where the '
                "tree already places them: it would start done. Fix: name another object as "
                f'the receptacle, {EXPLICIT[3:]}.'
            )
    if task.kind == "place" and task.receptacle != rel["context"]:
        for node in task.objects:  # the tree may not start the task done
            if [node, "ON"] in [list(x) for x in layout.tree.get(task.receptacle, [])] or [
                node, "IN"] in [list(x) for x in layout.tree.get(task.receptacle, [])]:  # fmt: skip
                raise LayoutError(
                    f'{f}: the task puts "{node}" {task.relation} "{task.receptacle}", and the '
                    f"tree already places it there: it would start done. Fix: place "
                    f'"{node}" on the context ("{rel["context"]}") in "tree".'
                )
    return task
