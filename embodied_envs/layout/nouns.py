"""Which of a layout's nodes a noun phrase of its task sentence names (``layout/sentence.py``
reads the sentence; docs/tasks.md states the rules).

A node is named by its name ("pen1", "grey bowl", "茶杯": any script) or by the head noun of its
``objs_desc`` ("a wide fruit bowl" -> bowl); a plural ("the pens") or a quantifier ("both",
"all") names every node of that noun; "fruit" names the nodes whose noun is a fruit and
"objects"/"everything" names them all. Adjectives single a node out: a colour, material,
size or position word in the phrase must be in the node's name or description (where it has
one); another adjective counts only where some node has it. A singular phrase that still names
several nodes is refused, never resolved to the first one.
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass

ARTICLES = frozenset(
    "the a an this that these those its their his her my your our one's".split()
)
QUANTIFIERS = frozenset("all both every each".split())  # every node the noun names ("both": 2)
# number words, joined as written ("twenty one", "a hundred"): a count that must be the number
# of nodes the noun names, or refused
ONES = ("zero one two three four five six seven eight nine ten eleven twelve thirteen fourteen "
         "fifteen sixteen seventeen eighteen nineteen").split()  # fmt: skip
TENS = "twenty thirty forty fifty sixty seventy eighty ninety".split()
NUMBERS = {w: k for k, w in enumerate(ONES)} | {w: 10 * k for k, w in enumerate(TENS, 2)}
SCALES = {"hundred": 100, "thousand": 1000, "million": 10**6, "billion": 10**9, "dozen": 12}
# a part of what the noun names, not which: refused ("some apples", "a few cans")
VAGUE = frozenset("some several few many most half couple any other another remaining".split())
PRONOUNS = frozenset("it them they itself themselves".split())
EVERYTHING = frozenset("object item thing everything stuff".split())  # (stems) all movers
FRUITS = frozenset(
    "fruit apple banana pear orange lemon lime peach plum grape strawberry cherry mango kiwi "
    "melon watermelon pineapple apricot avocado tangerine mandarin".split()
)
# words a node must carry (in its name or objs_desc) when a phrase names it with them: the
# ones that single out one of several similar objects
STRICT = frozenset(
    "red orange yellow green blue purple violet pink brown black white grey gray silver gold "
    "golden beige tan cyan teal navy maroon dark light wooden wood metal metallic plastic glass "
    "ceramic paper cardboard steel rubber leather fabric stone big small large little tiny tall "
    "short long wide narrow thin thick huge left right front back middle center centre first "
    "second third last other nearest closest farthest furthest leftmost rightmost upper lower "
    "top bottom".split()
)
# what a sentence may call a table-like context whatever its node is named ("on the table" of
# a desk)
SURFACES = frozenset("table desk counter countertop tabletop workbench bench surface".split())
# a participle that ends a phrase when a preposition follows ("a can lying on its side")
PARTICIPLE_NEXT = frozenset("on in at with by under inside against upright upside".split())
DESC_CUT = frozenset("with on in of that which for from and".split())


class Unread(Exception):
    """A part of the sentence the reader cannot resolve; the message says which and why.
    ``none``: the phrase names no node at all (not several, nor a mis-described one)."""

    def __init__(self, message: str, none: bool = False):
        super().__init__(message)
        self.none = none


class Miscount(Unread):
    """A count ("both", "three", "٣") that is not the number of nodes the phrase names."""


def words(text: str) -> list[str]:
    """Lower-case words in any script, Unicode-normalised (NFC: "café" typed either way is one
    word); apostrophes inside a word kept ("rubik's"), other punctuation and underscores
    separate words."""
    text = unicodedata.normalize("NFC", text).lower().replace("\u2019", "'")
    return re.findall(r"[^\W_]+(?:'[^\W_]+)*", text)


def number(w: str) -> int | None:
    """A number written in digits of any script ("3", "٣", "②"), else None.

    Raises:
        Unread: a number that is no count ("½", "2.5").
    """
    if not any(c.isnumeric() for c in w) or any(c.isalpha() and not c.isnumeric() for c in w):
        return None
    if all(unicodedata.decimal(c, None) is not None for c in w):
        return int("".join(str(unicodedata.decimal(c)) for c in w))
    v = unicodedata.numeric(w, None) if len(w) == 1 else None
    if v is None or v != int(v):
        raise Unread(f'"{w}" is not a count of objects')
    return int(v)


def counts(ws: list[str], names: set[str] = frozenset()) -> tuple[list[int], list[str]]:
    """The counts a phrase's words state ("both": 2, "twenty one", "٣"), and its other words
    (a number word of a node's name is the name's; digits are a count where not joined to a
    name, ``joined``)."""
    out, rest, run = [], [], None  # run: (total, current) of the number words being read
    for w in ws:
        word = w not in names and (w in NUMBERS or w in SCALES)
        if word:
            total, cur = run or (0, 0)
            if w in NUMBERS:
                cur += NUMBERS[w]
            elif w == "hundred" or w == "dozen":
                cur = max(cur, 1) * SCALES[w]
            else:
                total, cur = total + max(cur, 1) * SCALES[w], 0
            run = (total, cur)
            continue
        if run:
            out.append(sum(run))
            run = None
        if w == "both" and w not in names:
            out.append(2)
            rest.append(w)
        elif (n := number(w)) is not None:
            out.append(n)
        else:
            rest.append(w)
    if run:
        out.append(sum(run))
    return out, rest


def joined(ws: list[str]) -> list[str]:
    """A number after a word joined to it: "apple 1" (or "apple_1") -> apple1."""
    out: list[str] = []
    for w in ws:
        if out and w.isdigit() and not out[-1].isdigit():
            out[-1] += w
        else:
            out.append(w)
    return out


def stem(word: str) -> str:
    """A noun without a plural ending or trailing digits: pens, pen1 -> pen; boxes -> box."""
    word = re.sub(r"\d+$", "", word)
    for end, keep in (("ies", "y"), ("ches", "ch"), ("shes", "sh"), ("xes", "x"), ("ses", "s")):
        if word.endswith(end) and len(word) > len(end) + 1:
            return word[: -len(end)] + keep
    if word.endswith("s") and not word.endswith(("ss", "'s")) and len(word) > 3:
        return word[:-1]
    return word


def is_participle(ws: list[str], k: int) -> bool:
    """``ws[k]`` is a participle opening a description ("lying" in "a can lying on its side")."""
    w = ws[k]
    return (len(w) >= 5 and w.endswith("ing") and not w.endswith("thing") and k > 0
            and ws[k - 1] not in ARTICLES and k + 1 < len(ws)
            and ws[k + 1] in PARTICIPLE_NEXT)  # fmt: skip


def desc_head(desc: str) -> str | None:
    """The head noun of a description: "a blue soda can with a silver lid" -> can."""
    ws = words(desc.split(",")[0])
    for k, w in enumerate(ws):
        if w in DESC_CUT or is_participle(ws, k):
            ws = ws[:k]
            break
    heads = [s for s in (stem(w) for w in ws) if s]
    return heads[-1] if heads else None


@dataclass(frozen=True)
class Phrase:
    """A noun phrase as the sentence writes it: its words, and the words of its "with ..."
    description ("a mug with a handle")."""

    words: tuple[str, ...]
    with_words: tuple[str, ...] = ()

    def text(self) -> str:
        return " ".join(self.words + (("with",) + self.with_words if self.with_words else ()))

    def pronoun(self) -> bool:
        """"it", "them", "both of them"."""
        ws = set(self.words)
        return bool(ws & PRONOUNS) and ws <= PRONOUNS | QUANTIFIERS | {"of"}


class Nodes:
    """A layout's object nodes (all but the background) and what names each."""

    def __init__(self, layout):
        self.context = layout.relation["context"]
        self.names = [n for n in layout.objs_mapping if layout.objs_mapping[n] != "background"]
        desc = dict(layout.objs_desc or {})
        self.desc = {n: d for n in self.names if isinstance(d := desc.get(n), str) and d.strip()}
        self.raw = {n: tuple(joined(words(n))) for n in self.names}
        self.vocab, self.heads = {}, {}
        for n in self.names:
            name = [s for s in (stem(w) for w in self.raw[n]) if s]
            text = self.desc.get(n, "")
            self.vocab[n] = set(name) | {s for s in (stem(w) for w in words(text)) if s}
            self.heads[n] = {h for h in (name[-1] if name else None, desc_head(text)) if h}
        self.name_words = {w for n in self.names for w in (*self.raw[n], *words(n))}
        # words of names and descriptions: "left" in "the left shoe", "jelly" in "the jelly jar"
        self.all_words = self.name_words | {w for d in self.desc.values() for w in words(d)}

    def shown(self, nodes) -> str:
        return ", ".join(f'{n} ("{self.desc[n]}")' if n in self.desc else n for n in nodes)

    def resolve(self, phrase: Phrase, among: list[str] | None = None) -> tuple[list[str], bool]:
        """The nodes ``phrase`` names (among ``among``, all object nodes by default) and
        whether it names them in the plural.

        Raises:
            Unread: it names none of them, or several where it says one.
        """
        pool = self.names if among is None else among
        said = f'"{phrase.text()}"'
        ws = [w for w in phrase.words if w not in ARTICLES]
        if vague := [w for w in ws if w in VAGUE and w not in self.name_words]:
            raise Unread(f'{said} says "{vague[0]}": name the objects, or all of them')
        ws = joined(ws)  # "apple 1": apple1; "2 apples" stays a count
        count, ws = counts(ws, self.name_words)
        plural = bool(count) or any(w in QUANTIFIERS for w in ws)
        if len(set(count)) > 1:
            raise Unread(f"{said} states two counts ({', '.join(map(str, count))})")
        ws = [w for w in ws if w not in QUANTIFIERS]
        if "of" in ws:  # "the box of tools": the box; "one of the pens": refused by its noun
            k = ws.index("of")
            ws, tail = ws[:k], ws[k + 1 :]
        else:
            tail = []
        if not ws:
            raise Unread(f"{said} names no object", none=True)
        exact = [n for n in pool if self.raw[n] and tuple(ws[-len(self.raw[n]) :]) == self.raw[n]]
        head = stem(ws[-1])
        plural = plural or head != ws[-1].rstrip("0123456789") or head in EVERYTHING | {"fruit"}
        if not exact and re.fullmatch(r"\D+\d+", ws[-1]):  # a numbered name names that node
            raise Unread(f"{said} names no object of the layout", none=True)
        if exact:
            longest = max(len(self.raw[n]) for n in exact)
            cands = [n for n in exact if len(self.raw[n]) == longest]
            mods = [stem(w) for w in ws[: -longest] + tail + list(phrase.with_words)]
        else:
            if head in EVERYTHING:
                cands = list(pool)
            elif head == "fruit":
                cands = [n for n in pool if self.heads[n] & FRUITS]
            else:
                cands = [n for n in pool if head in self.heads[n]]
            if not cands and head in SURFACES and self.heads.get(self.context, set()) & SURFACES:
                cands = [self.context] if self.context in pool else []
            mods = [stem(w) for w in ws[:-1] + tail + list(phrase.with_words)]
        if not cands:
            raise Unread(f"{said} names no object of the layout", none=True)
        # another object named after it or as its owner ("the bowl of fruit", "the pen with the
        # apple", "the tray's bowl"), not a word of its own: refused (a compound such as "the
        # fruit bowl" is read as the bowl)
        for m in {stem(w) for w in tail + list(phrase.with_words)} | {
                w[:-2] for w in ws if w.endswith("'s")}:  # fmt: skip
            others = [n for n in self.names if n not in cands and (
                m in self.heads[n] or m == "fruit" and self.heads[n] & FRUITS)]  # fmt: skip
            if others and not any(m in self.vocab[n] for n in cands):
                raise Unread(f'{said} names "{m}" ({self.shown(others)}) beside the object: '
                             "name one object in each place")  # fmt: skip
        for m in (m for m in mods if m and m not in ARTICLES):
            if m in STRICT:
                kept = [n for n in cands if m in self.vocab[n] or n not in self.desc]
            elif any(m in self.vocab[n] for n in cands):
                kept = [n for n in cands if m in self.vocab[n]]
            else:
                continue  # an adjective no candidate carries ("the small mug" of one mug)
            if not kept:
                raise Unread(f'{said}: no object is described "{m}" ({self.shown(cands)})')
            cands = kept
        if len(cands) > 1 and not plural:
            raise Unread(
                f"{said} names {len(cands)} objects ({self.shown(cands)}): say which, with a "
                "word of its objs_desc"
            )
        if count and count[0] != len(cands):
            raise Miscount(f"{said} counts {count[0]}, and it names {len(cands)} "
                         f"({self.shown(cands)})")  # fmt: skip
        return cands, plural
