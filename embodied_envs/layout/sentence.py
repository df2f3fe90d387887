"""The task sentence reader: ``relation["task_desc"]`` -> a ``Task``, or a one-line refusal.

It reads the sentence's own words in order, with no model and no network, and grades nothing it
cannot read exactly (docs/tasks.md states the grammar and what it refuses). ``layout/clauses.py``
reads the words into clauses (the grammar); this module says which task the clauses state.

At most one clause puts or moves; the others pick up or hold the same objects ("it",
"them"). The receptacle is the first place a destination names, in the sentence's order;
a place naming the context, or where the movers already stand, says where they are.
"""

from __future__ import annotations

from dataclasses import replace

from embodied_envs.layout.clauses import Clause, Reader
from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.nouns import (
    ARTICLES,
    EVERYTHING,
    Miscount,
    Nodes,
    Phrase,
    Unread,
    stem,
)
from embodied_envs.layout.task_model import EXPLICIT, Task
from embodied_envs.layout.vocabulary import (
    DIRECTIONAL,
    FORMS,
    HOLD,
    INTO,
    LEAVE,
    MOVE,
    PICK,
    PLACE,
    REGIONS,
    check_words,
    tokens,
)

MAX_SENTENCE = 1000  # characters: a task_desc is one sentence; a longer one is refused unread
QUOTE = 200  # characters of the sentence a refusal quotes


def refuse(f: str, sentence: str, why: str) -> LayoutError:
    """The one-line refusal: the sentence, what could not be read, the forms and the fix."""
    said = " ".join(sentence.split())  # one line, however it was written
    if len(said) > QUOTE:
        said = said[:QUOTE] + "..."
    return LayoutError(
        f'{f}: relation["task_desc"] "{said}" is not a task this env grades ({why}). '
        f"Understood: {FORMS}. Fix: rephrase it so, {EXPLICIT}."
    )


def _movers(c: Clause, nodes: Nodes, manipulated: list[str]) -> list[str]:
    """The nodes the clause's objects name, wherever the layout lists them (manipulated,
    distractor or another object; never the context): a plural ("the apples", "both apples",
    "all the fruit") names every node of its noun; a singular phrase names one node, sought
    first among ``manipulated_objs`` (a hint: "the apple" of a red mover apple and a green
    distractor apple is the mover) and else among all the objects; "everything", the movers."""
    found: list[str] = []
    objects = [n for n in nodes.names if n != nodes.context]
    for p in c.objects:
        ws = [w for w in p.words if w not in ARTICLES]
        if ws and stem(ws[-1]) in EVERYTHING:
            got = nodes.resolve(p, manipulated)[0]
        else:
            try:
                got, plural = nodes.resolve(p, manipulated)
                if plural:  # a plural names every node of its noun, wherever listed
                    got = nodes.resolve(p, objects)[0]
            except Miscount:
                got = nodes.resolve(p, objects)[0]  # "both apples", one a distractor
            except Unread:
                got = _anywhere(p, nodes, objects)
        found += [n for n in got if n not in found]
    return found


def _anywhere(p: Phrase, nodes: Nodes, objects: list[str]) -> list[str]:
    """The nodes ``p`` names among all the layout's objects; the context is not one."""
    try:
        return nodes.resolve(p, objects)[0]
    except Unread as e:
        if e.none and nodes.context in _named(p, nodes):
            raise Unread(f'"{p.text()}" is the context ({nodes.context}), which stays where it '
                         "is: name an object on it") from None  # fmt: skip
        if e.none:
            raise Unread(f'"{p.text()}" names no object of the layout '
                         f"(objects: {', '.join(objects)})", none=True) from None  # fmt: skip
        raise


def _named(p: Phrase, nodes: Nodes) -> list[str]:
    try:
        return nodes.resolve(p)[0]
    except Unread:
        return []


def _above(nodes: list[str], parents: dict[str, str]) -> set[str]:
    """Every node the ``nodes`` stand on or in, up the tree."""
    out = set()
    for n in nodes:
        while n in parents and parents[n] not in out:
            n = parents[n]
            out.add(n)
    return out


def _receptacle(places, nodes: Nodes, movers: list[str], parents: dict[str, str]):
    """The first place that is not where the movers already stand (nor the context); the
    others must say where it or they stand."""
    named = []
    for prep, rel, p in places:
        where, _ = nodes.resolve(_region(prep, p))
        if len(where) > 1:
            raise Unread(f'"{prep} {p.text()}" names {len(where)} objects: name one receptacle')
        named.append((where[0], rel, f"{prep} {p.text()}"))
    around = _above(movers, parents) | {nodes.context}
    first = next((x for x in named if x[0] not in around), named[0])
    if first[0] in movers:
        raise Unread(f'"{first[2]}" names an object it also moves')
    rec_around = _above([first[0]], parents)
    for node, _, said in named:
        if node != first[0] and node not in around | rec_around:
            raise Unread(f'"{first[2]}" and "{said}" name two destinations: name one')
    return first[0], first[1]


def _located(c: Clause, nodes: Nodes, movers: list[str], parents: dict[str, str]) -> None:
    """After a pick or hold verb, or beside a move's direction, "in"/"on" say where the movers
    stand ("pick up the pen on the desk", "move the pen in the tray to the left"). Naming
    anything else, it may mean a destination ("lift the pen on the tray", "move the pen on the
    plate to the left" of a pen on the table), and a held object is placed nowhere: refused."""
    around = _above(movers, parents) | {nodes.context}
    for prep, _, p in c.places:
        if c.kind == HOLD:
            raise Unread(f'"{c.verb} ... {prep} {p.text()}" asks to leave it there (or holds it '
                         "there), which moves nothing to grade: say put ... in/on, or pick up")
        where, _ = nodes.resolve(_region(prep, p))
        if prep in DIRECTIONAL:
            raise Unread(f'"{c.verb} ... {prep} {p.text()}": a held object is not placed; say '
                         "put")  # fmt: skip
        if not set(where) <= around:
            then = ("beside a direction, in/on says where they stand" if c.directions else
                    f'a destination after "{c.verb}" takes into or onto')  # fmt: skip
            raise Unread(f'"{c.verb} ... {prep} {p.text()}": not where the objects stand; '
                         f"{then}")  # fmt: skip


def _region(prep: str, p: Phrase) -> Phrase:
    """The object a destination names: "on (the) top of the shelf" -> the shelf; a part of an
    object or a side ("the middle of the table", "the left") refused."""
    ws = [w for w in p.words if w not in ARTICLES]
    if "of" in ws:
        k = ws.index("of")
        part, rest = ws[:k], ws[k + 1 :]
        if part and part[-1] in ("top", "surface") and INTO.get(prep, "on") == "on":
            return Phrase(tuple(rest), p.with_words)
        if part and part[-1] in REGIONS | {"top", "surface"}:
            raise Unread(f'"{prep} {p.text()}" is a part of an object: only in or on the '
                         "object as a whole is graded")  # fmt: skip
    elif any(w in REGIONS for w in ws):
        raise Unread(f'"{prep} {p.text()}" names a side, not an object: only in or on an '
                     "object is graded")  # fmt: skip
    return p


def read_sentence(sentence: str, layout) -> Task:
    """The task ``sentence`` states against ``layout``'s nodes.

    Raises:
        Unread: what it could not read, and why.
    """
    said = " ".join(sentence.split())  # its words: spaces and line breaks around them not read
    if len(said) > MAX_SENTENCE:
        raise Unread(f"it is {len(said)} characters long, over the {MAX_SENTENCE} read")
    nodes = Nodes(layout)
    manipulated = list(layout.relation["manipulated_objs"])
    toks = tokens(sentence, str(layout.relation.get("robot", "")))
    check_words(toks, nodes.name_words)
    clauses = Reader(toks, nodes).clauses()
    if leave := next((c for c in clauses if c.kind == LEAVE), None):
        raise Unread(f'"{leave.verb}" asks to leave the objects as they are, which moves nothing '
                     "to grade: say put, pick up or move")  # fmt: skip
    first = clauses[0]
    if not first.objects or any(p.pronoun() for p in first.objects):
        raise Unread(f'"{first.verb}" names no object')
    movers = _movers(first, nodes, manipulated)
    parents = {kid: parent for parent, kids in layout.tree.items() for kid, *_ in kids}
    acts = []
    for c in clauses:
        if c.objects and c is not first and not all(p.pronoun() for p in c.objects):
            if set(_movers(c, nodes, manipulated)) != set(movers):
                raise Unread(f'"{c.verb}" names other objects than "{first.verb}": two tasks '
                             "in one sentence; state one")  # fmt: skip
        # after a pick verb only into/onto is a destination ("pick up the pen on the desk")
        places = c.places if c.kind != PICK else [x for x in c.places if x[0] in DIRECTIONAL]
        if c.kind in (PICK, HOLD):  # the others say where the objects stand
            places = places if c.kind == PICK else []
            _located(replace(c, places=[x for x in c.places if x not in places]), nodes, movers,
                     parents)  # fmt: skip
        if c.kind == MOVE and c.directions and places:
            if any(x[0] in DIRECTIONAL for x in places):
                raise Unread("it states a direction and a destination: state one")
            _located(replace(c, places=places), nodes, movers, parents)  # as after a pick
            places = []  # "move the pen in the tray to the left": where it is
        if len(c.directions) > 1:
            raise Unread("it states two directions: state one")
        if acts and not (places or c.directions):  # "put it in the bowl, then lift it"
            raise Unread(f'"{c.verb}" after the destination or direction: it would not end '
                         "there; state one task")  # fmt: skip
        if places or c.directions:
            acts.append((c, places))
        elif c.kind == PLACE:
            raise Unread(f'"{c.verb}" names no destination (in or on an object)')
        elif c.kind == MOVE:
            raise Unread(f'"{c.verb}" names no direction and no destination')
    if len(acts) > 1:
        raise Unread("it states two destinations or moves: state one task")
    goal = any(c.goal for c in clauses)
    if not acts:
        if len(movers) != 1:
            raise Unread(f"a pick grades one object; it names {len(movers)} "
                         f"({', '.join(movers)})")  # fmt: skip
        return Task("pick", tuple(movers))
    c, places = acts[0]
    if goal:
        raise Unread("it names the goal and another destination: state one")
    if c.directions:
        return Task("move", tuple(movers), direction=c.directions[0])
    receptacle, relation = _receptacle(places, nodes, movers, parents)
    objects = tuple(n for n in movers if n != receptacle)
    if not objects:
        raise Unread("it names nothing to move but the receptacle")
    return Task("place", objects, receptacle, relation)


def parse_task(sentence: str, layout, f: str) -> Task:
    """The task ``sentence`` states, against ``layout``'s nodes; ``f`` names the file.

    Raises:
        LayoutError: one line quoting the sentence, saying which part it could not read.
    """
    try:
        return read_sentence(sentence, layout)
    except Unread as e:
        raise refuse(f, sentence, str(e)) from None
