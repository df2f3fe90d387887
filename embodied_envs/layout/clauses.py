"""The task sentence's words read into clauses, left to right: each verb's objects, places,
directions and "at the goal", or ``Unread`` saying what could not be read (``layout/sentence.py``
turns the clauses into a ``Task``; docs/tasks.md states the grammar and what it refuses):

    sentence := [please] clause {(and | then | ,) clause} [.]
    clause   := VERB [up|down] OBJECTS {modifier}
    modifier := from/off/out of PLACE           a source: read over
              | in/into/inside/on/onto/on top of PLACE   a destination (after a pick verb only
                                                  into/onto; in/on there say where it is)
              | [to the] left/right/forward/backward    a move's direction (robot's frame)
              | at the goal | up | down | an adverb ("slightly", "gently")
"""

from __future__ import annotations

from dataclasses import dataclass, field

from embodied_envs.layout.nouns import (
    ARTICLES,
    PRONOUNS,
    QUANTIFIERS,
    Nodes,
    Phrase,
    Unread,
    is_participle,
)
from embodied_envs.layout.vocabulary import (
    ADVERBS,
    DIRECTION_WORDS,
    FRAMES,
    INTO,
    MOVE,
    PARTICLES,
    POSES,
    RELATIVE,
    ROBOT_WORDS,
    SOURCES,
    SPEAKER,
    VERBS,
    VIEW,
)


@dataclass
class Clause:
    """One verb's clause: what it does, to what, and where."""

    verb: str
    kind: str
    objects: list[Phrase] = field(default_factory=list)
    places: list[tuple[str, str, Phrase]] = field(default_factory=list)  # (prep, rel, place)
    directions: list[str] = field(default_factory=list)
    goal: bool = False


class Reader:
    """One sentence's words, read left to right (each word once: linear in its length)."""

    def __init__(self, toks: list[str], nodes: Nodes):
        self.t, self.k, self.nodes = toks, 0, nodes

    def peek(self, ahead: int = 0) -> str | None:
        return self.t[self.k + ahead] if self.k + ahead < len(self.t) else None

    def after_links(self) -> str | None:
        """The first word after a run of "and", "then", "," and adverbs."""
        j = self.k
        while j < len(self.t) and (self.t[j] in ("and", "then", ",") or self.adverb(self.t[j])):
            j += 1
        return self.t[j] if j < len(self.t) else None

    def adverb(self, w: str) -> bool:
        """"slightly", "gently", "precisely" (a word of no node's name)."""
        return (w in ADVERBS or w.endswith("ly")) and w not in self.nodes.name_words

    def modifier(self, w: str) -> bool:
        """A direction or "-ly" word of a node's name or description before another of its
        words, not a stop: "the left shoe", "the jelly jar"."""
        nxt = self.peek(1)
        return (w in DIRECTION_WORDS or self.adverb(w) or w.endswith("ly")) and (
            w in self.nodes.all_words and nxt is not None and nxt in self.nodes.all_words
            and not self.stop(nxt))  # fmt: skip

    def stop(self, w: str) -> bool:
        """Whether ``w`` ends a noun phrase."""
        return (w in INTO or w in SOURCES or w in PARTICLES or w in DIRECTION_WORDS
                or w in ("and", "then", ",", "to", "at", "with", "away", "toward", "towards",
                         "closer", "nearer", "farther", "further", "back")
                or (w in ADVERBS and w not in self.nodes.name_words)
                or (w in POSES and w not in self.nodes.all_words)
                or (w.endswith("ly") and w not in self.nodes.name_words))  # fmt: skip

    def phrase(self) -> Phrase:
        """A noun phrase up to the next stop word (with its "with ..." description)."""
        ws, with_words = [], []
        noun = pronoun = False  # a word other than an article or quantifier read; a pronoun
        while (w := self.peek()) is not None:
            if w == "a" and self.peek(1) in ("bit", "little"):
                break  # "move the lamp a bit to the left"
            if w == "of" or not self.stop(w) or self.modifier(w):
                if ws and is_participle(self.t, self.k) and w not in self.nodes.name_words:
                    self.k += 1  # "a can lying on its side": the description is read over
                    if self.peek() in INTO or self.peek() in SOURCES:
                        self.k += 1
                        self.phrase()
                    continue
                if ws and ws[-1] != "of" and (w in ARTICLES and noun or pronoun):
                    raise Unread(f'"{" ".join(ws)} {w}" runs two phrases together')
                noun = noun or w not in ARTICLES and w not in QUANTIFIERS
                pronoun = pronoun or w in PRONOUNS
                ws.append(w)
                self.k += 1
            elif w == "with" and ws and not with_words:
                self.k += 1
                while (v := self.peek()) is not None and not self.stop(v):
                    with_words.append(v)
                    self.k += 1
            else:
                break
        return Phrase(tuple(ws), tuple(with_words))

    def objects(self) -> list[Phrase]:
        """The clause's objects: one phrase, or several joined by "and" / ","."""
        out = [self.phrase()]
        while self.peek() in ("and", ",") and self.after_links() not in VERBS:
            while self.peek() in ("and", ","):
                self.k += 1
            out.append(self.phrase())
        if len(out) > 1 and out[0].words[:1] == ("both",):  # "both the pen and the apple"
            out[0] = Phrase(out[0].words[1:], out[0].with_words)
        return [p for p in out if p.words]

    def place(self, prep: str) -> tuple[str, str, Phrase]:
        """A destination (or a location): its preposition, relation and the place it names."""
        rel = INTO[prep]
        if prep == "on" and self.peek() == "top" and self.peek(1) == "of":
            self.k += 2
        elif prep == "inside" and self.peek() == "of":
            self.k += 1
        elif prep in ("on", "in") and self.peek() == "to":
            self.k += 1
            prep = prep + "to"
        p = self.phrase()
        if not [w for w in p.words if w not in ARTICLES]:
            if self.peek() in (*DIRECTION_WORDS, "back", "front"):
                raise Unread(f'"{prep} {p.text()} {self.peek()}" names a side, not an object: '
                             "only in or on an object is graded")  # fmt: skip
            raise Unread(f'"{prep}" is followed by no object')
        return prep, rel, p

    def frame(self, said: str, ws) -> None:
        """A side or direction in the speaker's, a person's or an object's frame ("to our
        left", "towards me", "to its left"): refused, only the robot's is known."""
        if whose := [w for w in ws if w in SPEAKER or w in FRAMES]:
            raise Unread(f'"{said}" is relative to "{whose[0]}" (the speaker, a person or an '
                         "object), unknown here: say left, right, forward or backward (the "
                         "robot's)")  # fmt: skip

    def direction_to(self) -> str | None:
        """After "to": the direction it states, or None for "to the goal"."""
        said = self.phrase().words
        self.frame(" ".join(("to", *said, *self.t[self.k : self.k + 1])), said)
        ws = [w for w in said if w not in ARTICLES]
        if ws and ws[-1] == "goal":
            return None
        if self.peek() in ("back", "front"):
            raise Unread(f'"to the {self.peek()}" is not a direction it grades (left, right, '
                         "forward, backward)")  # fmt: skip
        if self.peek() in DIRECTION_WORDS:
            w = self.t[self.k]
            self.k += 1
            return self.direction(w, prefix=ws)
        raise Unread(f'"to {" ".join(ws)}" says neither in nor on: say "in" or "on" the object')

    def direction(self, w: str, prefix=()) -> str:
        """A direction word, refused where it is relative to an object ("to the left of X"),
        "to the left side of the table" (the context) kept."""
        if any(p not in ("side", "edge", "end", "part", "robot's") for p in prefix):
            raise Unread(f'"to {" ".join(prefix)} {w}" is not a direction it grades')
        if self.peek() == "hand" and self.peek(1) == "side":
            self.k += 1  # "the left-hand side"
        part = self.peek() in ("side", "edge", "end", "part") and self.peek(1) == "of"
        if not part and self.peek() == "side" and self.peek(1) not in self.nodes.all_words:
            self.k += 1  # "to the left side"
        if self.peek() == "of" or part:
            self.k += 2 if part else 1
            of = self.phrase()
            self.frame(f"{w} of {of.text()}", of.words)
            where, _ = self.nodes.resolve(of)
            if not part or where != [self.nodes.context]:
                raise Unread(
                    f'"{w} of {of.text()}" is a direction relative to an object: only left, '
                    "right, forward and backward in the robot's frame are graded"
                )
        return DIRECTION_WORDS[w]

    def relative(self, w: str) -> str:
        """"towards the robot" (backward), "away (from the robot)" (forward); relative to
        anything else, refused."""
        said = w
        if w in ("closer", "nearer", "farther", "further") and self.peek() in ("to", "from"):
            said, self.k = f"{w} {self.peek()}", self.k + 1
        elif w == "away" and self.peek() != "from":
            return "forward"
        elif w == "away":
            said, self.k = f"{w} from", self.k + 1
        whom = self.phrase()
        self.frame(f"{said} {whom.text()}", whom.words)
        toward = w in ("toward", "towards", "closer", "nearer")
        if toward and not set(whom.words) - ARTICLES and self.peek() in DIRECTION_WORDS:
            self.k += 1  # "towards the left"
            return self.direction(self.t[self.k - 1])
        if set(whom.words) & ROBOT_WORDS:
            return "backward" if toward else "forward"
        raise Unread(f'"{w} {whom.text()}" is a direction relative to an object: only left, '
                     "right, forward and backward in the robot's frame are graded")  # fmt: skip

    def clause(self) -> Clause:
        verb = self.t[self.k]
        if verb not in VERBS:
            raise Unread(f'"{verb}" is not a verb it knows')
        self.k += 1
        c = Clause(verb, VERBS[verb])
        while self.peek() in PARTICLES:
            self.k += 1
        if self.peek() in ("and", "then") and self.peek(1) in VERBS:
            self.k += 1  # "pick and place the pen in the bowl": the last verb's clause
            return self.clause()
        c.objects = self.objects()
        while (w := self.peek()) is not None:
            if w in ("and", ",") and self.adverb(self.t[self.k - 1]) and self.adverb(
                    self.peek(1) or ""):  # fmt: skip
                self.k += 1  # "gently and precisely"
                continue
            if w in ("and", "then", ","):
                if self.after_links() in VERBS:
                    break
                nxt = self.after_links()
                if nxt is None:
                    self.k = len(self.t)
                    break
                if (nxt in ARTICLES or nxt in self.nodes.name_words or nxt in INTO
                        or nxt in DIRECTION_WORDS or nxt in ("to", "at", "back")):  # fmt: skip
                    raise Unread(
                        f'after "{" ".join(self.t[:self.k])}" it goes on with "{nxt} ...": two '
                        "destinations, directions or tasks in one sentence; state one"
                    )
                raise Unread(f'"{nxt}" is not a verb it knows')
            self.k += 1
            if w in POSES and c.kind == MOVE and w in ("diagonally", "sideways"):
                raise Unread(f'"{w}" is not a direction it grades (left, right, forward, '
                             "backward)")  # fmt: skip
            if w in POSES:
                said = "upside down" if w == "upside" else w
                raise Unread(f'"{said}" asks for a pose: only where the object ends is graded')
            if w == "by" and self.peek() == "a" and self.peek(1) in ("bit", "little"):
                continue  # "left by a bit"
            ahead = {self.peek(), self.peek(1)}  # "to left", "to the left"
            if c.kind != MOVE and (w in DIRECTION_WORDS or w in RELATIVE or (
                    w == "to" and DIRECTION_WORDS.keys() & ahead)):  # fmt: skip
                raise Unread(f'"{c.verb}" with a direction ("{w}"): a direction is graded after '
                             "move, push, slide, shift, drag or nudge")  # fmt: skip
            if w in ADVERBS or w.endswith("ly") or (w == "a" and self.peek() in ("bit", "little")):
                continue  # "slightly", "gently", "a bit"
            if w in PARTICLES:
                if c.kind == MOVE and not c.places:
                    raise Unread(f'"{w}" is not a direction it grades (left, right, forward, '
                                 "backward)")  # fmt: skip
                continue
            if w in SOURCES:
                if w == "out" and self.peek() == "of" or w == "off" and self.peek() == "of":
                    self.k += 1
                src = self.phrase()  # where it is taken from: read over
                if set(src.words) & (VIEW | SPEAKER | {"my", "our", "your"}):
                    raise Unread(f'"{w} {src.text()}" is a point of view: only the robot\'s '
                                 "left, right, forward and backward are graded")  # fmt: skip
            elif w in INTO:
                c.places.append(self.place(w))
            elif w == "to":
                d = self.direction_to()
                if d is None:
                    c.goal = True
                else:
                    c.directions.append(d)
            elif w in DIRECTION_WORDS:
                c.directions.append(self.direction(w))
            elif w == "back" and c.kind == MOVE and not c.places:
                raise Unread('"back" may say towards the robot or away from it: say forward or '
                             "backward")  # fmt: skip
            elif w == "back":
                continue  # "put it back in the mug"
            elif w in RELATIVE:
                c.directions.append(self.relative(w))
            elif w == "at":
                ws = [v for v in self.phrase().words if v not in ARTICLES]
                if not ws or ws[-1] != "goal":
                    raise Unread(f'"at {" ".join(ws)}" is a place it does not grade: only in '
                                 "or on an object")  # fmt: skip
                c.goal = True
            elif w == "with":
                raise Unread(f'"with {self.phrase().text()}" after the object is not a place')
            else:
                raise Unread(f'it could not read "{w}" after "{" ".join(self.t[: self.k - 1])}"')
        return c

    def clauses(self) -> list[Clause]:
        if not self.t:
            raise Unread("it is empty")
        out = [self.clause()]
        while self.k < len(self.t):
            while self.peek() in ("and", "then", ",") or self.peek() in ADVERBS:
                self.k += 1
            out.append(self.clause())
        return out
