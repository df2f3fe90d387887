"""The task sentence reader's words: its verbs, prepositions and directions, the words it
refuses wherever they stand, and the sentence split into words (``layout/sentence.py`` reads
them; docs/tasks.md lists them)."""

from __future__ import annotations

import re

from embodied_envs.layout.nouns import Unread
from embodied_envs.robots import ROBOT_NAMES

PICK, PLACE, MOVE, HOLD = "pick", "place", "move", "hold"
VERBS = {
    **dict.fromkeys("pick lift grab grasp take raise get fetch remove retrieve collect".split(),
                    PICK),
    **dict.fromkeys("put place set drop transfer lay shove toss throw stick insert stack stash "
                    "store load pop deposit tuck plop dump position".split(), PLACE),
    **dict.fromkeys("move push slide shift drag nudge".split(), MOVE),
    **dict.fromkeys("hold keep".split(), HOLD),
}  # fmt: skip
# destination prepositions and the relation each states; the directional ones (a destination
# even after a pick verb)
INTO = {"in": "in", "into": "in", "inside": "in", "within": "in", "on": "on", "onto": "on",
        "upon": "on", "atop": "on"}  # fmt: skip
DIRECTIONAL = frozenset({"into", "onto"})
SOURCES = frozenset({"from", "off", "out"})
DIRECTION_WORDS = {
    "left": "left", "leftward": "left", "leftwards": "left", "right": "right",
    "rightward": "right", "rightwards": "right", "forward": "forward", "forwards": "forward",
    "ahead": "forward", "backward": "backward", "backwards": "backward",
}  # fmt: skip
ROBOT_WORDS = frozenset({"robot", "you", "me", "yourself", "base", "robot's"})
ADVERBS = frozenset("slightly gently carefully slowly quickly just again also too please "
                    "now there bit little way".split())  # fmt: skip
FILLERS = frozenset({"please", "kindly", "now", "first", "then", "carefully", "gently"})
PARTICLES = frozenset({"up", "down"})
RELATIVE = frozenset({"away", "toward", "towards", "closer", "nearer", "farther", "further"})
# how the object should stand: not graded, so refused
POSES = frozenset("vertically horizontally upright upside sideways diagonally flat".split())
# a part of an object, not the object: refused as a destination; "top"/"surface" mean on it
REGIONS = frozenset("middle center centre side edge corner end bottom back front rear left right "
                    "part area half interior".split())  # fmt: skip
NEGATION = frozenset("not no never nor neither without except instead rather avoid nothing "
                     "none but cannot".split())  # fmt: skip
CHOICE = frozenset("or either if unless until when whenever while after before once otherwise "
                   "whether because which where whose".split())  # fmt: skip
# other spatial relations: the word, as the refusal quotes it
RELATIONS = {
    "next": "next to", "beside": "beside", "besides": "beside", "behind": "behind",
    "under": "under", "underneath": "underneath", "below": "below", "beneath": "beneath",
    "above": "above", "over": "over", "near": "near", "nearby": "near", "between": "between",
    "among": "among", "amongst": "among", "around": "around", "against": "against",
    "across": "across", "along": "along", "alongside": "alongside", "opposite": "opposite",
    "adjacent": "adjacent to", "beyond": "beyond", "through": "through", "outside": "outside",
    "front": "front of", "by": "by", "close": "close to", "underside": "under",
}  # fmt: skip
UNITS = frozenset("cm mm m centimeter centimeters centimetre centimetres millimeter millimeters "
                  "meter meters metre metres inch inches foot feet".split())  # fmt: skip
# EmbodiedGen's ", robot franka." (a robot's name after "robot" ends the sentence)
ROBOT_SUFFIX = re.compile(r"[\s,;]*(?:with |using |by )?(?:the )?robot[ :=]*([^\W_][\w-]*)[\s.!]*$",
                          re.IGNORECASE)  # fmt: skip
EMBODIEDGEN_ROBOTS = frozenset({"franka", "ur5", "piper", "panda"})  # its prompt's robot names
FORMS = ('"Pick up X", "Put/Place X in/on B" (also "Pick X and put it in B"), '
         '"Move X to the left/right/forward/backward"')  # fmt: skip


def tokens(sentence: str, robot: str = "") -> list[str]:
    """Words and the punctuation that splits sentences, without EmbodiedGen's ", robot franka."
    suffix (``robot``, or a robot name it or this package knows), a closing full stop and
    leading courtesies."""
    text = sentence.strip()
    m = ROBOT_SUFFIX.search(text)
    if m and m.start() > 0 and m.group(1).lower() in EMBODIEDGEN_ROBOTS | set(ROBOT_NAMES) | {
            robot.lower()}:  # fmt: skip
        text = text[: m.start()]
    toks = re.findall(r"[^\W_]+(?:'[^\W_]+)*|[,;:.!?]",
                      text.lower().replace("\u2019", "'").replace("_", " "))  # fmt: skip
    while toks and toks[-1] in ".!?":
        toks.pop()
    k = 0
    while k < len(toks) and (toks[k] in FILLERS or toks[k] == ","):
        k += 1
    if k + 1 < len(toks) and toks[k] in ("can", "could", "would", "will") and toks[k + 1] == "you":
        k += 2
    return toks[k:]


def check_words(toks: list[str], names: set[str]) -> None:
    """Words that state what the env cannot grade, wherever they stand."""
    for k, w in enumerate(toks):
        if w in names:
            continue
        if w in NEGATION or w.endswith("n't"):
            raise Unread(f'it negates ("{w}"): say only what to do')
        if w in CHOICE:
            raise Unread(f'"{w}" adds a choice, a condition or a clause: state one task')
        if w in ".;:!?":
            raise Unread("it holds more than one sentence: state one task")
        if w in RELATIONS and not (w == "close" and toks[k + 1 : k + 2] != ["to"]):
            raise Unread(f'"{RELATIONS[w]}" is a place it does not grade: only in or on')
        if w in UNITS or (w.isdigit() and toks[k + 1 : k + 2] and toks[k + 1] in UNITS):
            raise Unread("it states a distance: a move is graded by its direction only")
