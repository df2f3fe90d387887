"""The task sentence reader's words: its verbs, prepositions and directions, the words it
refuses wherever they stand, and the sentence split into words (``layout/clauses.py`` and
``layout/sentence.py`` read them; docs/tasks.md lists them)."""

from __future__ import annotations

import re
import unicodedata

from embodied_envs.layout.nouns import NUMBERS, Unread
from embodied_envs.robots import ROBOT_NAMES

PICK, PLACE, MOVE, HOLD, LEAVE = "pick", "place", "move", "hold", "leave"
VERBS = {
    **dict.fromkeys("pick lift grab grasp take raise get fetch remove retrieve collect".split(),
                    PICK),
    **dict.fromkeys("put place set drop transfer lay toss throw stick insert stack stash "
                    "store stow load pack pop deposit tuck plop dump position lower".split(),
                    PLACE),
    # these take a direction ("shove it to the left") or a destination ("shove it in the box")
    **dict.fromkeys("move push slide shift drag nudge shove pull roll carry bring relocate "
                    "reposition".split(), MOVE),
    **dict.fromkeys("hold keep".split(), HOLD),
    # "leave the pen on the tray", "let it stand": where it is, nothing to grade (refused)
    **dict.fromkeys("leave let".split(), LEAVE),
}  # fmt: skip
# "The pen should be placed in the bowl": the passive's participles and their verbs
PARTICIPLES = {
    **{f: v for v in VERBS for f in (v + "ed", v + "d" if v.endswith("e") else v + "ed",
                                     v + v[-1] + "ed", v[:-1] + "ied" if v.endswith("y") else v)},
    **dict(put="put", set="set", laid="lay", thrown="throw", taken="take", brought="bring",
           held="hold", kept="keep", got="get", gotten="get", slid="slide", stuck="stick",
           left="leave", let="let"),
}  # fmt: skip
# "should be placed", "needs to be placed", "is to be placed": the modal before "be"
MODALS = frozenset("should must shall will would can could".split())
MODALS_TO = frozenset("need needs has have is are ought".split())  # before "to be"
# "Your task is to ...", "The goal: ...": what a sentence may open with before its verb
TASK_NOUNS = frozenset("task goal job objective mission instruction instructions command".split())
OPENERS = [o.split() for o in (
    "you should", "you must", "you need to", "you have to", "you will", "you are to",
    "you are going to", "i want you to", "i need you to", "i would like you to", "i'd like you to",
    "we need you to", "we want you to", "try to", "go ahead and", "make sure to",
    "the robot should", "the robot must", "the robot needs to", "the robot has to",
    "the robot will", "the robot is to")]  # fmt: skip
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
ROBOT_WORDS = frozenset({"robot", "you", "yourself", "base", "robot's"})
# the speaker, another person or an object: a side or direction in their frame is unknown here
SPEAKER = frozenset({"me", "us", "myself", "ourselves", "i", "we", "him", "her", "mine", "ours"})
FRAMES = frozenset({"my", "our", "your", "yours", "his", "her", "their", "its", "one's"})
VIEW = frozenset({"perspective", "view", "viewpoint", "point"})  # "from my point of view"
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


def _opener(toks: list[str], k: int) -> int:
    """How many words at ``toks[k]`` open the sentence before its verb: "your task is to",
    "the goal:", "you should", "i want you to" (0 for none)."""
    j = k + (toks[k : k + 1] in (["your"], ["the"], ["my"], ["our"]))
    if toks[j : j + 1] and toks[j] in TASK_NOUNS:
        noun = j = j + 1
        for w in ("is", ":", "to"):  # "your task is to", "task:", "the goal: to"
            j += toks[j : j + 1] == [w]
        return j - k if j > noun else 0
    for o in OPENERS:
        if toks[k : k + len(o)] == o:
            return len(o)
    return 0


def _passive(toks: list[str]) -> list[str]:
    """"the pen should be placed in the bowl" -> "place the pen in the bowl" (a modal, "be" and
    a participle after the objects); other sentences as they are."""
    if not toks or toks[0] in VERBS:
        return toks
    for i in range(1, len(toks) - 1):
        if toks[i] != "be":
            continue
        if toks[i - 1] in MODALS:
            start = i - 1
        elif toks[i - 1] == "to" and i >= 2 and toks[i - 2] in MODALS_TO:
            start = i - 2
        else:
            return toks
        j = i + 1
        while j < len(toks) and toks[j].endswith("ly") and toks[j] not in PARTICIPLES:
            j += 1  # "should be carefully placed"
        if start == 0 or j >= len(toks) or toks[j] not in PARTICIPLES:
            return toks
        rest = toks[j + 1 :]
        parts = []
        while rest[:1] and rest[0] in PARTICLES:
            parts, rest = parts + rest[:1], rest[1:]
        by = [k for k, w in enumerate(rest) if w == "by"]
        if by and [w for w in rest[by[-1] + 1 :] if w != "the"] in (["you"], ["robot"]):
            rest = rest[: by[-1]]  # "... by the robot"
        # "picked up and placed in the cup": each participle after a link, its verb
        rest = [PARTICIPLES[w] if w in PARTICIPLES and rest[k - 1 : k] in (["and"], ["then"],
                [","]) and w not in ("left", "put", "set") else w for k, w in enumerate(rest)]
        return [PARTICIPLES[toks[j]], *parts, *toks[:start], *rest]  # fmt: skip
    return toks


def tokens(sentence: str, robot: str = "") -> list[str]:
    """Words and the punctuation that splits sentences, without EmbodiedGen's ", robot franka."
    suffix (``robot``, or a robot name it or this package knows), closing punctuation, leading
    courtesies and openers ("Your task is to"); Unicode-normalised (NFC); a full stop, "!",
    "?" or ";" between two sentences links them as ", then" does (they must state one task);
    the passive turned active ("the pen should be placed in the bowl")."""
    text = unicodedata.normalize("NFC", sentence).strip()
    m = ROBOT_SUFFIX.search(text)
    if m and m.start() > 0 and m.group(1).lower() in EMBODIEDGEN_ROBOTS | set(ROBOT_NAMES) | {
            robot.lower()}:  # fmt: skip
        text = text[: m.start()]
    toks = re.findall(r"\d+(?:\.\d+)+|[^\W_]+(?:'[^\W_]+)*|[,;:.!?]",
                      text.lower().replace("\u2019", "'").replace("_", " "))  # fmt: skip
    toks = ["," if w in ".!?;" else w for w in toks]  # sentences: linked; the last: ended
    while toks and toks[-1] in ",:":
        toks.pop()
    while toks[-2:] in ([",", "robot"], [",", "thanks"]) or toks[-3:] == [",", "thank", "you"]:
        toks = toks[: -3 if toks[-1] == "you" else -2]  # ", robot." ", thank you!"
        while toks and toks[-1] in ",:":
            toks.pop()
    # "slide it over to the left": "over" before "to" adds nothing
    toks = [w for k, w in enumerate(toks) if not (w == "over" and toks[k + 1 : k + 2] == ["to"])]
    names = EMBODIEDGEN_ROBOTS | set(ROBOT_NAMES) | {robot.lower(), "robot"}
    k, j = 0, -1
    while k != j:  # "Robot, please ...", "Could you please ...", "Franka: ..."
        j = k
        while k < len(toks) and (toks[k] in FILLERS or toks[k] == ","):
            k += 1
        if toks[k : k + 2] in (["can", "you"], ["could", "you"], ["would", "you"],
                                ["will", "you"]) or (k + 1 < len(toks) and toks[k] in names
                                                     and toks[k + 1] in (",", ":")):  # fmt: skip
            k += 2
        elif k < len(toks):
            k += _opener(toks, k)
    return _passive(toks[k:])


def check_words(toks: list[str], names: set[str]) -> None:
    """Words that state what the env cannot grade, wherever they stand."""
    for k, w in enumerate(toks):
        if w in names:
            continue
        if w in NEGATION or w.endswith("n't"):
            raise Unread(f'it negates ("{w}"): say only what to do')
        if w in CHOICE:
            raise Unread(f'"{w}" adds a choice, a condition or a clause: state one task')
        if w == ":":
            raise Unread(f'it could not read ":" after "{" ".join(toks[:k])}": state one task')
        if _amount(w) or w == "by" and _amount(" ".join(toks[k + 1 : k + 3])):
            raise Unread(f'it states a distance ("{" ".join(toks[k : k + 3])}"): a move is graded '
                         "by its direction only")  # fmt: skip
        if w == "by" and toks[k + 1 : k + 2] == ["a"] and toks[k + 2 : k + 3] in (["bit"],
                                                                                ["little"]):
            continue  # "left by a bit"
        if w in RELATIONS and not (w == "close" and toks[k + 1 : k + 2] != ["to"]):
            raise Unread(f'"{RELATIONS[w]}" is a place it does not grade: only in or on')
        if w in UNITS or (w.isdigit() and toks[k + 1 : k + 2] and toks[k + 1] in UNITS):
            raise Unread("it states a distance: a move is graded by its direction only")


def _amount(w: str) -> bool:
    """A number that is no count of objects ("0.1"), or one with a unit after "by" ("10 cm",
    "ten centimetres", "a few inches")."""
    first, _, unit = w.partition(" ")
    return bool(re.fullmatch(r"\d+(?:\.\d+)+", first)) or unit in UNITS and (
        first.isnumeric() or first in NUMBERS or first in ("a", "an", "one", "few"))
