"""The task sentence reader (layout/sentence.py): every sentence read as written or refused in
one line that quotes it and says which part failed; never read as something else.

The scenes are relations in EmbodiedGen's exact form (its layout designer's keys: task_desc,
task, robot, background, context, manipulated_objs, distractor_objs; every object ON the
context, as its hierarchy prompt places them). The table holds EmbodiedGen's own example task
list (apps/assets/example_layout/task_list.txt), the sentences of its prompts' examples, and
phrasings an LLM writes that the rules were not written from."""

import json
import random
import time
from types import SimpleNamespace

import pytest
from conftest import DATA

from embodied_envs.layout import LayoutInfo
from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.pools import with_assets
from embodied_envs.layout.sentence import MAX_SENTENCE
from embodied_envs.layout.task import Task, parse_task, resolve_task

F = "scene.json"


def eg_scene(task_desc, manipulated, distractors=(), context="table", desc=None,
             robot="franka", category="pick and place", tree=None):  # fmt: skip
    """A layout's relation as EmbodiedGen's LAYOUT_DISASSEMBLE_PROMPT writes it, its nodes and
    tree as LAYOUT_HIERARCHY_PROMPT places them."""
    nodes = [*manipulated, *distractors]
    mapping = {"room": "background", context: "context"}
    mapping |= {n: "manipulated_objs" for n in manipulated}
    mapping |= {n: "distractor_objs" for n in distractors}
    relation = {"task_desc": task_desc, "task": category, "robot": robot, "background": "room",
                "context": context, "manipulated_objs": list(manipulated),
                "distractor_objs": list(distractors)}  # fmt: skip
    tree = tree or {"room": [[context, "FLOOR"], [robot, "IN"]],
                    context: [[n, "ON"] for n in nodes]}  # fmt: skip
    return SimpleNamespace(relation=relation, objs_mapping=mapping, objs_desc=desc or {},
                           tree=tree)  # fmt: skip


# scenes for the phrasings: one per kind of ambiguity
OFFICE = dict(manipulated=["pen", "apple"], distractors=["mug", "tray", "bowl"],
              desc={"pen": "a black ballpoint pen", "apple": "a red apple",
                    "mug": "a white ceramic mug", "tray": "a wooden serving tray",
                    "bowl": "a blue plastic bowl"})  # fmt: skip
MUGS = dict(manipulated=["pen"], distractors=["mug1", "mug2", "tray"],
            desc={"mug1": "a white ceramic mug", "mug2": "a black ceramic mug with a logo"})
APPLES = dict(manipulated=["apple1", "apple2"], distractors=["plate"],
              desc={"apple1": "a shiny red apple", "apple2": "a green apple"})
# the pen IN the tray as EmbodiedGen's hierarchy prompt nests it; the others on the table
PEN_IN_TRAY = dict(manipulated=["pen", "apple"], distractors=["tray", "plate"],
                   tree={"room": [["table", "FLOOR"], ["franka", "IN"]],
                         "table": [["tray", "ON"], ["apple", "ON"], ["plate", "ON"]],
                         "tray": [["pen", "IN"]]})  # fmt: skip
TEA = dict(manipulated=["茶杯"], distractors=["托盘"], desc={"茶杯": "a small teacup"})


def S(manipulated, distractors=(), context="table", desc=None):
    return dict(manipulated=manipulated, distractors=distractors, context=context, desc=desc)


R = "refused: "
CASES = [
    # --- EmbodiedGen's task list (apps/assets/example_layout/task_list.txt), 20 sentences
    ("Place the pen in the mug on the desk", S(["pen", "mug"], ["notebook"], "desk"),
     "place [pen] in mug"),
    ("Get the pen from the table and put it inside the cup", S(["pen", "cup"], ["book"]),
     "place [pen] in cup"),
    ("Put the fruit on the table on the plate", S(["apple", "pear", "plate"], ["knife"]),
     "place [apple, pear] on plate"),
    ("Put the apples on the table on the plate", S(["apple1", "apple2", "plate"]),
     "place [apple1, apple2] on plate"),
    ("Put the pens in the grey bowl", S(["pen1", "pen2", "grey bowl"], ["notepad", "cup"]),
     "place [pen1, pen2] in grey bowl"),
    ("Put the spoon on the plate in the table", S(["spoon", "plate"], ["cup"]),
     "place [spoon] on plate"),
    ("Put the green lid on the desk", S(["green lid"], ["jar"], "desk"), R + "would start done"),
    ("Put the pen on the tray", S(["pen", "tray"]), "place [pen] on tray"),
    ("Move the plate forward", S(["plate"], ["cup"]), "move [plate] forward"),
    ("Move the lamp to the left", S(["lamp"], ["book"], "desk"), "move [lamp] left"),
    ("Move the pillow to the right", S(["pillow"], [], "bed"), "move [pillow] right"),
    ("Pick up the cup and put on the middle of the table", S(["cup"]),
     R + '"on the middle of the table" is a part of an object'),
    ("Close the laptop", S(["laptop"], [], "desk"), R + '"close" is not a verb it knows'),
    ("Close the red jar with the lid on the table", S(["red jar", "lid"]),
     R + '"close" is not a verb it knows'),
    ("Pick the cloth and shove it in the box", S(["cloth", "box"]), "place [cloth] in box"),
    ("Pick up the marker from the table and put it in the bowl",
     S(["marker"], ["mug", "notebook", "bowl"]), "place [marker] in bowl"),
    ("Pick up the charger and move it slightly to the left", S(["charger"], ["lamp"], "desk"),
     "move [charger] left"),
    ("Move the jar to the left side of the desk", S(["jar"], ["cup"], "desk"), "move [jar] left"),
    ("Pick the rubik's cube on the top of the desk", S(["rubik's cube"], ["pen"], "desk"),
     "pick [rubik's cube]"),
    ("Move the mug to the right", S(["mug"], ["plate"]), "move [mug] right"),
    # --- the examples of EmbodiedGen's layout prompts, as they write task_desc
    ("Pick up the marker from the table and put it in the bowl.",
     S(["marker"], ["mug", "notebook", "bowl"]), "place [marker] in bowl"),
    ("Remove all the objects from the white basket and put them on the table, robot piper.",
     S(["banana", "mobile phone"], ["plate", "white basket"]), R + "would start done"),
    ("Pick up the rope on the chair and put it in the box, robot franka.",
     S(["rope", "box"], ["magazine"], "chair"), "place [rope] in box"),
    ("Pick up the seal tape and plastic from the counter and put them in the open drawer and "
     "close it.", S(["seal tape", "plastic", "opened drawer"], ["scissors"], "counter"),
     R + '"close" is not a verb it knows'),
    ("Put the rubik's cube on the top of the shelf.", S(["rubik's cube"], ["pen", "cup",
     "toy car"], "shelf"), R + "would start done"),  # the tree has it on the shelf
    ("Put the pens in the grey bowl.", S(["pen1", "pen2", "grey bowl"], ["notepad", "cup"]),
     "place [pen1, pen2] in grey bowl"),
    ("Put the marker on top of the book.", S(["marker", "book"], ["pen holder", "notepad"],
     "desk"), "place [marker] on book"),
    ("Put the marker in the cup on the counter.", S(["marker", "cup"], ["plate", "spoon"],
     "counter"), "place [marker] in cup"),
    # --- phrasings an LLM writes (office: pen, apple movers; mug, tray, bowl distractors)
    ("Lift the pen onto the tray", OFFICE, "place [pen] on tray"),
    ("Put the pen not in the mug but on the tray", OFFICE, R + 'it negates ("not")'),
    ("Put the pen in the mug and the apple on the tray", OFFICE,
     R + "two destinations, directions or tasks"),
    ("Place the pen in front of the mug", OFFICE, R + '"front of" is a place it does not'),
    ("Put the pen on the left of the tray", OFFICE, R + '"on the left" names a side'),
    ("Push the pen towards the tray", OFFICE, R + '"towards the tray" is a direction relative'),
    ("Move the pen to the left of the mug", OFFICE, R + '"left of the mug" is a direction rel'),
    ("Slide the apple closer to the bowl", OFFICE, R + '"closer the bowl" is a direction rel'),
    ("Move the pen away from the mug", OFFICE, R + '"away the mug" is a direction relative'),
    ("Put the notebook on the tray", OFFICE, R + '"the notebook" names no object of the layout'),
    ("Put the mug on the tray", OFFICE, "place [mug] on tray"),  # a distractor named: a mover
    ("Place the pen next to the bowl", OFFICE, R + '"next to" is a place it does not grade'),
    ("Put the apple beside the mug", OFFICE, R + '"beside" is a place'),
    ("Put the apple behind the bowl", OFFICE, R + '"behind" is a place'),
    ("Put the pen under the tray", OFFICE, R + '"under" is a place'),
    ("Place the apple between the mug and the bowl", OFFICE, R + '"between" is a place'),
    ("Put the apple near the tray", OFFICE, R + '"near" is a place'),
    ("Hold the pen above the mug", OFFICE, R + '"above" is a place'),
    ("Move the pen in the tray to the left", PEN_IN_TRAY, "move [pen] left"),  # where it is
    ("Move the pen in the tray to the left", OFFICE, R + '"move ... in the tray": not where the'),
    ("Push the apple on the plate to the right", PEN_IN_TRAY, R + '"push ... on the plate": not'),
    ("Slide the pen on the table left", PEN_IN_TRAY, "move [pen] left"),  # up the tree: the table
    ("Pick up the pen on the table", OFFICE, "pick [pen]"),
    ("Could you put the apple into the bowl, please?", OFFICE, "place [apple] in bowl"),
    ("Drop the apple in the bowl.", OFFICE, "place [apple] in bowl"),
    ("Toss the pen into the mug", OFFICE, "place [pen] in mug"),
    ("Grab the apple and place it on the tray", OFFICE, "place [apple] on tray"),
    ("Pick up the apple, then put it in the bowl", OFFICE, "place [apple] in bowl"),
    ("First pick up the pen and then put it inside the mug", OFFICE, "place [pen] in mug"),
    ("Take the pen out of the mug and put it on the tray", OFFICE, "place [pen] on tray"),
    ("Put the pen into the mug, robot franka.", OFFICE, "place [pen] in mug"),
    ("Place the apple on top of the tray", OFFICE, "place [apple] on tray"),
    ("Put the apple in the bowl or on the tray", OFFICE, R + '"or" adds a choice'),
    ("Don't put the pen in the mug", OFFICE, R + 'it negates ("don\'t")'),
    ("Never move the pen to the left", OFFICE, R + 'it negates ("never")'),
    ("Put the pen in the mug if it is empty", OFFICE, R + '"if" adds a choice, a condition'),
    ("Put the pen in the mug. Then put the apple on the tray.", OFFICE, R + "two tasks"),
    ("Put the pen in the mug; put the apple on the tray", OFFICE, R + "two tasks"),
    ("Move the pen 10 cm to the left", OFFICE, R + "it states a distance"),
    ("Move the pen left", OFFICE, "move [pen] left"),
    ("Move the pen a bit towards the left", OFFICE, "move [pen] left"),
    ("Place the mug upside down on the tray", OFFICE, R + '"upside down" asks for a pose'),
    ("Shift the apple to the right", OFFICE, "move [apple] right"),
    ("Push the apple forward", OFFICE, "move [apple] forward"),
    ("Drag the pen backwards", OFFICE, "move [pen] backward"),
    ("Push the apple towards the robot", OFFICE, "move [apple] backward"),
    ("Move the pen up", OFFICE, R + '"up" is not a direction it grades'),
    ("Put the pen in the mug and put the apple on the tray", OFFICE,
     R + '"put" names other objects than "put": two tasks'),
    ("Pick up the pen and the apple", OFFICE, R + "a pick grades one object; it names 2"),
    ("Put the pen and the apple in the bowl", OFFICE, "place [pen, apple] in bowl"),
    ("Put everything on the tray", OFFICE, "place [pen, apple] on tray"),
    ("Put the pen in the cup", OFFICE, R + '"the cup" names no object of the layout'),
    ("Put the pen in the mug on the tray", OFFICE, R + "name two destinations"),
    ("Put the pen on the tray in the mug", OFFICE, R + "name two destinations"),
    ("Stack the apple on the bowl", OFFICE, "place [apple] on bowl"),
    ("Put the pen in it", OFFICE, R + '"it" names no object'),
    ("Put the pen the apple in the bowl", OFFICE, R + '"the pen the" runs two phrases together'),
    ("Pick up it the pen", OFFICE, R + '"it the" runs two phrases together'),
    ("Put the pen in", OFFICE, R + '"in" is followed by no object'),
    ("Put it in the mug", OFFICE, R + '"put" names no object'),
    ("Place the pen", OFFICE, R + '"place" names no destination'),
    ("Move the apple", OFFICE, R + '"move" names no direction and no destination'),
    ("Open the drawer", OFFICE, R + '"open" is not a verb it knows'),
    ("Rotate the mug by 90 degrees", OFFICE, R + '"by" is a place it does not grade'),
    ("Put the pen into the mug and close the lid", OFFICE, R + '"close" is not a verb'),
    ("Put the pen in the mug and then put it on the tray", OFFICE,
     R + "two destinations or moves"),
    ("Move the pen to the left and forward", OFFICE, R + 'goes on with "forward ...": two'),
    ("Put the apple in the bowl gently", OFFICE, "place [apple] in bowl"),
    ("Carefully place the apple in the bowl", OFFICE, "place [apple] in bowl"),
    ("Place the apple into the blue bowl", OFFICE, "place [apple] in bowl"),
    ("Place the apple into the red bowl", OFFICE, R + 'no object is described "red"'),
    ("Pick up the pen and hold it above the table", OFFICE, R + '"above" is a place'),
    ("Bring the apple to the tray", OFFICE, R + '"to tray" says neither in nor on'),
    ("Put the pen to the tray", OFFICE, R + '"to tray" says neither in nor on'),
    ("Put the pen at the edge of the tray", OFFICE, R + '"at edge of tray" is a place it does'),
    ("Set the apple down on the tray", OFFICE, "place [apple] on tray"),
    ("Put down the apple on the tray", OFFICE, "place [apple] on tray"),
    ("Put the apple on the tray on the table", OFFICE, "place [apple] on tray"),
    ("Put the apple on the table on the tray", OFFICE, "place [apple] on tray"),
    ("Put the apple on the table", OFFICE, R + "would start done"),
    ("PUT THE PEN IN THE MUG!", OFFICE, "place [pen] in mug"),
    ("Put the pen inside of the mug", OFFICE, "place [pen] in mug"),
    ("Put the pen inside the mug on the right", OFFICE, R + '"on the right" names a side'),
    ("Put the apple into the bowl on the left", OFFICE, R + '"on the left" names a side'),
    ("Place the pen vertically in the mug", OFFICE, R + '"vertically" asks for a pose'),
    ("Push the apple back", OFFICE, R + '"back" may say towards the robot or away'),
    ("Put the apple in the bowl, which is on the table", OFFICE, R + '"which" adds a choice'),
    ("Move the apple to the tray", OFFICE, R + '"to tray" says neither in nor on'),
    ("Put the apple to the left", OFFICE, R + '"put" with a direction ("to")'),
    ("Push the apple away from the robot", OFFICE, "move [apple] forward"),
    ("Move the apple closer to the robot", OFFICE, "move [apple] backward"),
    ("Pick up both the pen and the apple and put them on the tray", OFFICE,
     "place [pen, apple] on tray"),
    ("Put the fruit in the bowl", OFFICE, "place [apple] in bowl"),
    ("Put the pen in to the mug", OFFICE, "place [pen] in mug"),
    ("Insert the pen into the mug", OFFICE, "place [pen] in mug"),
    ("Put the pen in the mug without spilling it", OFFICE, R + 'it negates ("without")'),
    ("Put the apple in the bowl slowly and carefully", OFFICE, "place [apple] in bowl"),
    ("Pick up the pen from the table and drop it into the mug", OFFICE, "place [pen] in mug"),
    ("Lift the apple and put it down in the bowl", OFFICE, "place [apple] in bowl"),
    ("Put the apple in the bowl and the pen in the mug", OFFICE, R + "two destinations"),
    ("Move the pen to the right side of the table", OFFICE, "move [pen] right"),
    ("Move the pen to the right side of the tray", OFFICE, R + '"right of the tray" is a dir'),
    ("Push the apple to the far left", OFFICE, R + '"to far left" is not a direction'),
    ("Place the pen inside the mug that is next to the bowl", OFFICE, R + '"next to"'),
    ("Put the apple and the pen on the tray", OFFICE, "place [apple, pen] on tray"),
    ("Pick up the pen and hold it", OFFICE, "pick [pen]"),
    ("Pick up the red apple and hold it at the green goal.", OFFICE, "pick [apple]"),
    ("Raise the apple", OFFICE, "pick [apple]"),
    ("Grasp the mug", OFFICE, "pick [mug]"),
    ("Pick up the table", OFFICE, R + '"the table" is the context (table), which stays where'),
    ("Put the black pen on the tray", OFFICE, "place [pen] on tray"),
    ("Put the green apple on the tray", OFFICE, R + 'no object is described "green"'),
    ("Place the pen in the mug, then move the apple to the left", OFFICE,
     R + '"move" names other objects than "place"'),
    ("Put the pen in the wooden tray", OFFICE, "place [pen] in tray"),
    ("Put the pen on the bowl's rim", OFFICE, R + "names no object"),
    ("   ", OFFICE, "pick [pen]"),  # blank: no sentence, the first mover picked
    # several similar nodes: adjectives of objs_desc single one out, or it is refused
    ("Put the pen in the black mug", MUGS, "place [pen] in mug2"),
    ("Put the pen in the mug with a logo", MUGS, "place [pen] in mug2"),
    ("Put the pen in the white mug", MUGS, "place [pen] in mug1"),
    ("Put the pen in the mug", MUGS, R + '"the mug" names 2 objects'),
    ("Put the pen in the red mug", MUGS, R + 'no object is described "red"'),
    ("Put the pen in mug1", MUGS, "place [pen] in mug1"),
    ("Put the red apple on the plate", APPLES, "place [apple1] on plate"),
    ("Put apple 2 on the plate", APPLES, "place [apple2] on plate"),
    ("Put the apple 3 on the plate", APPLES, R + '"the apple 3" names no object'),
    ("Put an apple on the plate", APPLES, R + '"an apple" names 2 objects'),
    ("Put the 2 apples on the plate", APPLES, "place [apple1, apple2] on plate"),
    ("Put the apples on the plate", APPLES, "place [apple1, apple2] on plate"),
    ("Put both apples on the plate", APPLES, "place [apple1, apple2] on plate"),
    ("Put the apple on the plate", APPLES, R + '"the apple" names 2 objects'),
    ("Pick up the green apple", APPLES, "pick [apple2]"),
    ("Pick up the yellow apple", APPLES, R + 'no object is described "yellow"'),
    # node names in any script
    ("Put the 茶杯 on the 托盘", TEA, "place [茶杯] on 托盘"),
    ("Pick up the small 茶杯", TEA, "pick [茶杯]"),
    ("把茶杯放在托盘上", TEA, R + "is not a verb it knows"),
]  # fmt: skip


def _reading(sentence, scene):
    layout = eg_scene(sentence, **{k: v for k, v in scene.items() if v is not None})
    try:
        return resolve_task(layout, F).describe()
    except LayoutError as e:
        assert len(e.problems) == 1 and "\n" not in str(e), str(e)
        assert str(e).startswith(F + ": "), str(e)
        return "refused: " + str(e)


@pytest.mark.parametrize("sentence, scene, expected", CASES, ids=[c[0][:60] for c in CASES])
def test_each_sentence_is_read_as_written_or_refused_in_one_line(sentence, scene, expected):
    got = _reading(sentence, scene)
    if expected.startswith(R):
        assert got.startswith(R) and expected[len(R) :] in got, got
        if "would start done" not in expected:  # the sentence quoted, the structured form shown
            assert f'"{" ".join(sentence.split())}" is not a task this env grades (' in got
            assert 'relation["task_spec"], e.g. {"kind": "place"' in got
    else:
        assert got == expected


def test_the_table_is_wide():
    """EmbodiedGen's 20 sentences and its prompts' 7, and over 60 other phrasings."""
    assert len(CASES) >= 27 + 60
    read = [c for c in CASES if not c[2].startswith(R)]
    assert len(read) > len(CASES) / 2


def test_the_receptacle_follows_the_sentence_not_the_node_order():
    for sentence, want in (("Put the apple on the table into the bowl", "bowl"),
                           ("Put the apple on the table onto the tray", "tray")):  # fmt: skip
        for order in (["tray", "bowl"], ["bowl", "tray"]):
            scene = eg_scene(sentence, ["apple"], order)
            assert resolve_task(scene, F).receptacle == want


def test_a_locative_names_where_the_movers_are():
    """"Put the pen in the mug on the tray": where the tree has the mug on the tray, "on the
    tray" says where the mug is; where both stand on the table, two destinations."""
    tree = {"room": [["table", "FLOOR"]], "table": [["pen", "ON"], ["tray", "ON"]],
            "tray": [["mug", "ON"]]}  # fmt: skip
    scene = eg_scene("Put the pen in the mug on the tray", ["pen"], ["mug", "tray"], tree=tree)
    assert resolve_task(scene, F) == Task("place", ("pen",), "mug", "in")
    tree = {"room": [["table", "FLOOR"]], "table": [["tray", "ON"]], "tray": [["pen", "ON"]],
            "mug": []}  # fmt: skip
    tree["table"].append(["mug", "ON"])
    scene = eg_scene("Put the pen on the tray in the mug", ["pen"], ["mug", "tray"], tree=tree)
    assert resolve_task(scene, F) == Task("place", ("pen",), "mug", "in")


# --- robustness --------------------------------------------------------------------------
WORDS = ("put the a pen apple mug tray bowl in into on onto and then it them not left right to "
         "of from pick up move push , . ; ? next top side lift 茶杯 both all 10 cm robot franka "
         "away towards with by at goal hold please x' 'y ... -- é ß \n \t").split(" ")


def test_any_word_order_gives_a_reading_or_a_one_line_refusal():
    """Random sentences of the reader's own words and garbage: a Task or a LayoutError, never
    another exception; a reading names only nodes of the layout, and the same one whatever
    order the layout lists its nodes in."""
    rng = random.Random(49)
    nodes = {"pen", "apple", "mug", "tray", "bowl", "table"}
    reversed_order = {**OFFICE, "manipulated": OFFICE["manipulated"][::-1],
                      "distractors": OFFICE["distractors"][::-1]}  # fmt: skip

    def reading(sentence, scene):
        try:
            return parse_task(sentence, eg_scene(sentence, **scene), F)
        except LayoutError as e:
            assert len(e.problems) == 1 and "\n" not in str(e)
            return None

    read = 0
    for _ in range(3000):
        sentence = " ".join(rng.choice(WORDS) for _ in range(rng.randint(0, 14)))
        task = reading(sentence, OFFICE)
        other = reading(sentence, reversed_order)
        assert (task is None) == (other is None), sentence
        if task is None:
            continue
        read += 1
        assert set(task.objects) <= nodes - {"table"} and (task.receptacle or "pen") in nodes
        assert (set(task.objects), task.receptacle, task.relation, task.direction) == (
            set(other.objects), other.receptacle, other.relation, other.direction), sentence
    assert read > 0


def test_long_sentences_are_refused_at_once_and_reading_is_linear():
    layout = eg_scene("", **OFFICE)
    huge = "Put the pen " + "very " * 20_000 + "in the mug"  # 100 kB
    start = time.perf_counter()
    with pytest.raises(LayoutError, match=f"over the {MAX_SENTENCE} read"):
        parse_task(huge, layout, F)
    assert time.perf_counter() - start < 0.1
    for n in (10, 150):  # as long as it reads: the time grows with the length, not its square
        sentence = "Put the " + "shiny " * n + "pen in the mug"
        assert len(sentence) <= MAX_SENTENCE
        start = time.perf_counter()
        assert parse_task(sentence, layout, F) == Task("place", ("pen",), "mug", "in")
        assert time.perf_counter() - start < 0.1


# --- the structured task and EmbodiedGen's category ---------------------------------------
@pytest.mark.parametrize("category", ["pick and place", "single-arm pick", "place", "push", "",
                                      "object sorting", "dual-arm grasping"])  # fmt: skip
def test_embodiedgens_task_category_is_kept_and_never_graded(category):
    scene = eg_scene("Put the pen in the mug", **OFFICE)
    scene.relation["task"] = category
    assert resolve_task(scene, F) == Task("place", ("pen",), "mug", "in")
    assert scene.relation["task"] == category


@pytest.mark.parametrize(
    "spec, message",
    [({"kind": "pick", "objects": 3}, 'relation["task_spec"]["objects"] is 3'),
     ({"kind": "pick", "objects": True}, 'relation["task_spec"]["objects"] is True'),
     ({"kind": "pick", "objects": [1]}, 'relation["task_spec"]["objects"] is [1]'),
     ({"kind": 7}, 'relation["task_spec"]["kind"] is 7'),
     ({"kind": "place", "objects": ["pen"], "receptacle": ["mug"]}, '["receptacle"] is [\'mug'),
     ({"kind": "place", "objects": ["pen"], "receptacle": "mug", "relation": 1}, '"relation"] is'),
     ({"kind": "move", "objects": ["pen"], "direction": None}, '["direction"] is None'),
     ({"kind": "pick", "object": ["pen"]}, "unknown keys ['object']"),
     ("pick", 'relation["task_spec"] must be an object (dict)')],
)  # fmt: skip
def test_a_structured_task_of_wrong_types_is_refused_in_one_line(spec, message):
    scene = eg_scene("Put the pen in the mug", **OFFICE)
    scene.relation["task_spec"] = spec
    with pytest.raises(LayoutError) as e:
        resolve_task(scene, F)
    assert len(e.value.problems) == 1 and message in str(e.value) and "\n" not in str(e.value)


def test_the_structured_task_wins_and_a_dict_in_task_is_read_as_before():
    scene = eg_scene("Put the pen in the mug", **OFFICE)
    spec = {"kind": "move", "objects": ["apple"], "direction": "left"}
    scene.relation["task_spec"] = spec
    assert resolve_task(scene, F) == Task("move", ("apple",), direction="left")
    del scene.relation["task_spec"]
    scene.relation["task"] = spec  # where it lived before
    assert resolve_task(scene, F) == Task("move", ("apple",), direction="left")
    scene.relation["task_spec"] = spec
    with pytest.raises(LayoutError, match='both "task_spec" and "task"'):
        resolve_task(scene, F)
    scene.relation["task"] = 5
    with pytest.raises(LayoutError, match='relation\\["task"\\] is 5: EmbodiedGen writes'):
        resolve_task(scene, F)


# --- instruction = grade ------------------------------------------------------------------
def test_the_instruction_is_the_sentence_the_grade_was_read_from():
    """The sentence where the grade was read from it; a sentence built from the structured task
    where that is graded (the layout's task_desc then says nothing the grade follows), and
    where a pooled target replaced the sentence's object."""
    path = DATA / "layouts" / "place_tray.json"
    data = json.loads(path.read_text())
    layout = LayoutInfo.from_dict(data, source=path)
    assert layout.task == Task("place", ("mug",), "tray", "on")
    assert layout.instruction == "Place the mug on the tray."
    data["relation"]["task_spec"] = {"kind": "place", "objects": ["mug"], "receptacle": "bowl",
                                     "relation": "in"}  # fmt: skip
    graded = LayoutInfo.from_dict(data, source=path)
    assert graded.task == Task("place", ("mug",), "bowl", "in")
    assert graded.instruction == "Put an orange mug with a handle in a white bowl."
    drawn = with_assets(layout, {"mug": "../assets/cups/blue_cup"})
    assert drawn.task == layout.task and drawn.relation["task_spec"] == layout.task.spec()
    assert drawn.instruction == "Put blue cup on a red serving tray with low rims."
    assert "task_desc" not in drawn.relation and drawn.relation["task"] == "pick and place"
