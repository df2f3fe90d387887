"""The layout's task, read from the layout: what is graded and what the expert does.

Resolution, in order:

1. ``relation["task_spec"]`` (``TASK_FIELD``), a structured field (EmbodiedGen writes none),
   wins::

       "task_spec": {"kind": "place", "objects": ["pen"], "receptacle": "mug", "relation": "in"}
       "task_spec": {"kind": "move", "objects": ["lamp"], "direction": "left"}
       "task_spec": {"kind": "pick", "objects": ["can"]}

   A dict in ``relation["task"]`` (``LEGACY_FIELD``, where it lived before) is read the same.
   A string there is EmbodiedGen's task category ("pick and place", "single-arm pick"): kept in
   the layout as written, never graded.

2. else ``relation["task_desc"]``, read by ``layout/sentence.py`` against the layout's nodes:
   read exactly, or refused in one line that quotes it (docs/tasks.md: the grammar).

3. else, no sentence at all: ``pick`` of the first manipulated object.
"""

from __future__ import annotations

from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.sentence import QUOTE, parse_task
from embodied_envs.layout.task_model import (
    DIRECTION_XY,
    DIRECTIONS,
    EXPLICIT,
    KINDS,
    LEGACY_FIELD,
    MAX_MOVERS,
    MOVE_SHIFT,
    RELATIONS,
    TASK_FIELD,
    TASK_KEYS,
    Task,
)

# the keys each kind takes (TASK_KEYS: all of them); a key of another kind is refused
KIND_KEYS = {"pick": ("kind", "objects"), "place": ("kind", "objects", "receptacle", "relation"),
             "move": ("kind", "objects", "direction")}  # fmt: skip
EXAMPLES = {"pick": '{"kind": "pick", "objects": ["can"]}',
            "place": '{"kind": "place", "objects": ["pen"], "receptacle": "mug", "relation": "in"}',
            "move": '{"kind": "move", "objects": ["lamp"], "direction": "left"}'}  # fmt: skip

__all__ = [
    "DIRECTIONS", "DIRECTION_XY", "KINDS", "LEGACY_FIELD", "MAX_MOVERS", "MOVE_SHIFT", "RELATIONS",
    "TASK_FIELD", "Task", "parse_task", "resolve_task", "structured_spec",
]  # fmt: skip


def structured_spec(relation: dict, f: str) -> tuple[str, dict] | None:
    """The structured task's field and value: ``relation["task_spec"]``, or a dict in
    ``relation["task"]``; None where there is none (a string in ``relation["task"]`` is
    EmbodiedGen's category, not a task).

    Raises:
        LayoutError: both fields hold one, or ``task``/``task_spec`` has another type.
    """
    legacy = relation.get(LEGACY_FIELD)
    if legacy is not None and not isinstance(legacy, (str, dict)):
        raise LayoutError(
            f'{f}: relation["{LEGACY_FIELD}"] is {legacy!r}: EmbodiedGen writes a task category '
            f'there (a string such as "pick and place"). Fix: make it a string, or remove it.'
        )
    if TASK_FIELD in relation:
        if isinstance(legacy, dict):
            raise LayoutError(
                f'{f}: relation holds a structured task in both "{TASK_FIELD}" and '
                f'"{LEGACY_FIELD}". Fix: keep the one in "{TASK_FIELD}".'
            )
        return TASK_FIELD, relation[TASK_FIELD]
    return (LEGACY_FIELD, legacy) if isinstance(legacy, dict) else None


def _names(value, field: str, f: str, what: str) -> list[str]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise LayoutError(f"{f}: {field} is {value!r}: {what}. Fix: name them.")
    return value


def _missing(spec: dict, kind: str, keys, field: str, f: str) -> None:
    """Refuses a key of ``keys`` that ``kind`` takes and ``spec`` lacks."""
    if missing := [k for k in KIND_KEYS[kind] if k in keys and k not in spec]:
        raise LayoutError(
            f'{f}: {field} is a {kind} task without "{missing[0]}". Fix: add it ({kind} takes '
            f"{list(KIND_KEYS[kind])}), e.g. {EXAMPLES[kind]}."
        )


def _structured(key: str, spec, layout, f: str) -> Task:
    field = f'relation["{key}"]'
    if not isinstance(spec, dict):
        raise LayoutError(f"{f}: {field} must be an object (dict). Fix: {EXPLICIT[3:]}.")
    extra = sorted(set(spec) - set(TASK_KEYS), key=str)
    if extra:
        raise LayoutError(f"{f}: {field} has unknown keys {extra}; it takes {list(TASK_KEYS)}.")
    kind = spec.get("kind")
    if not isinstance(kind, str) or kind not in KINDS:
        raise LayoutError(f'{f}: {field}["kind"] is {kind!r}, expected one of {list(KINDS)}.')
    if other := [k for k in TASK_KEYS if k in spec and k not in KIND_KEYS[kind]]:
        owner = {"receptacle": "place", "relation": "place", "direction": "move"}[other[0]]
        raise LayoutError(
            f'{f}: {field} is a {kind} task, and "{other[0]}" is a {owner} task\'s key: it would '
            f'not be graded. Fix: remove "{other[0]}", or make "kind" "{owner}".'
        )
    _missing(spec, kind, ("objects", "direction"), field, f)
    nodes = [n for n in layout.objs_mapping if layout.objs_mapping[n] != "background"]
    things = [n for n in nodes if n != layout.relation["context"]]  # manipulated or distractor
    movers = f"each must be an object node of the layout other than the context {things}"
    objects = _names(spec["objects"], f'{field}["objects"]', f, movers)
    if not objects or not all(o in things for o in objects):
        raise LayoutError(f'{f}: {field}["objects"] is {objects!r}: {movers}. Fix: name them.')
    if twice := sorted({o for o in objects if objects.count(o) > 1}):
        raise LayoutError(f'{f}: {field}["objects"] names "{twice[0]}" twice: {objects!r}. Fix: '
                          "name each object once.")  # fmt: skip
    if kind == "pick" and len(objects) != 1:
        raise LayoutError(f'{f}: {field}: a pick task takes one object, got {objects}.')
    receptacle = relation = direction = None
    if kind == "place":
        receptacle, relation = spec.get("receptacle"), spec.get("relation")
        if not isinstance(receptacle, str) or receptacle not in nodes or receptacle in objects:
            raise LayoutError(
                f'{f}: {field}["receptacle"] is {receptacle!r}: it must be an object node of the'
                f" layout other than the movers ({nodes}). Fix: name it."
            )
        _missing(spec, kind, ("relation",), field, f)  # after the receptacle's type
        if not isinstance(relation, str) or relation not in RELATIONS:
            raise LayoutError(f'{f}: {field}["relation"] is {relation!r}, expected "in" or "on".')
    if kind == "move":
        direction = spec.get("direction")
        if not isinstance(direction, str) or direction not in DIRECTIONS:
            raise LayoutError(
                f'{f}: {field}["direction"] is {direction!r}, expected one of {list(DIRECTIONS)}.'
            )
    return Task(kind, tuple(objects), receptacle, relation, direction)


def _short(value) -> str:
    """``value`` as a refusal quotes it: one line, at most ``QUOTE`` characters."""
    said = " ".join(repr(value).split())
    return said if len(said) <= QUOTE else said[:QUOTE] + "..."


def resolve_task(layout, f: str, max_movers: int | None = None) -> Task:
    """``layout``'s task (a ``LayoutInfo`` or anything with its ``relation``, ``objs_mapping``,
    ``objs_desc`` and ``tree``), checked against the layout; ``f`` names the file in errors.
    ``max_movers``: the most movers the env observes (``MAX_MOVERS``, as ``LayoutInfo.task``
    reads it: the loader, so ``layout validate`` and ``gym.make`` alike); None: any number.

    Raises:
        LayoutError: a task that cannot be graded, or one already done as the file places it.
    """
    rel = layout.relation
    desc = rel.get("task_desc")
    if desc is not None and not isinstance(desc, str):
        raise LayoutError(
            f'{f}: relation["task_desc"] is {type(desc).__name__} {_short(desc)}: it must be the '
            f'task sentence, a string. Fix: write it as one string ("Put the pen in the mug"), '
            f'or remove it.'
        )
    spec = structured_spec(rel, f)
    said = ""  # where the task was read from, as a refusal quotes it
    if spec is not None:
        task = _structured(*spec, layout, f)
    elif isinstance(rel.get("task_desc"), str) and rel["task_desc"].strip():
        task = parse_task(rel["task_desc"], layout, f)
        said = f' read from relation["task_desc"] "{" ".join(rel["task_desc"].split())[:QUOTE]}"'
    else:
        task = Task("pick", (rel["manipulated_objs"][0],))
    if max_movers is not None and len(task.objects) > max_movers:
        field = spec[0] if spec else TASK_FIELD
        where = (f"name at most {max_movers} objects in the sentence, {EXPLICIT}" if said
                 else f'name at most {max_movers} in relation["{field}"]["objects"]')  # fmt: skip
        raise LayoutError(
            f"{f}: the task{said} moves {len(task.objects)} objects {list(task.objects)}; the "
            f"env observes at most MAX_MOVERS={max_movers} (envs/observation.py). Fix: {where}."
        )
    if task.kind == "place" and task.receptacle == rel["context"]:
        on_table = [n for n in task.objects if [n, "ON"] in [list(x) for x in
                    layout.tree.get(rel["context"], [])]]  # fmt: skip
        if on_table:
            raise LayoutError(
                f'{f}: the task{said} puts {on_table} on the context "{rel["context"]}", where the '
                "tree already places them: it would start done. Fix: name another object as "
                f'the receptacle, {EXPLICIT[3:]}.'
            )
    if task.kind == "place" and task.receptacle != rel["context"]:
        for node in task.objects:  # the tree may not start the task done
            if [node, "ON"] in [list(x) for x in layout.tree.get(task.receptacle, [])] or [
                node, "IN"] in [list(x) for x in layout.tree.get(task.receptacle, [])]:  # fmt: skip
                raise LayoutError(
                    f'{f}: the task{said} puts "{node}" {task.relation} "{task.receptacle}", '
                    f"and the tree already places it there: it would start done. Fix: place "
                    f'"{node}" on the context ("{rel["context"]}") in "tree".'
                )
    return task
