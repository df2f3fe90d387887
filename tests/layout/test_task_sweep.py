"""An adversarial sweep of the task-sentence reader (layout/sentence.py), written before reading
the reader or its own table: sentences as an LLM writes them for tabletop scenes, each with the
readings a careful person accepts ("place [pen] in bowl") or REFUSE where it may only be refused.
A sentence whose reading is clear must not be refused; one that cannot be graded exactly as written
must be. Every sentence of EmbodiedGen's example task list
(apps/assets/example_layout/task_list.txt) and of its layout prompts' examples is here. Scenes
are relations in EmbodiedGen's exact form."""

from types import SimpleNamespace

import pytest

from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.task import resolve_task

F = "sweep.json"
REFUSE = "REFUSE"


def scene(manipulated, distractors=(), context="table", desc=None, tree=None):
    """A layout as EmbodiedGen's layout designer and hierarchy prompts write it."""
    nodes = [*manipulated, *distractors]
    mapping = {"room": "background", context: "context"}
    mapping |= {n: "manipulated_objs" for n in manipulated}
    mapping |= {n: "distractor_objs" for n in distractors}
    relation = {"task": "pick and place", "robot": "franka", "background": "room",
                "context": context, "manipulated_objs": list(manipulated),
                "distractor_objs": list(distractors)}  # fmt: skip
    tree = tree or {"room": [[context, "FLOOR"], ["franka", "IN"]],
                    context: [[n, "ON"] for n in nodes]}  # fmt: skip
    return dict(relation=relation, objs_mapping=mapping, objs_desc=desc or {}, tree=tree)


DESK = scene(
    ["pen", "red apple", "green apple", "toy car"], ["mug_1", "mug_2", "tray", "bowl"], "desk",
    {"pen": "a black ballpoint pen", "red apple": "a shiny red apple",
     "green apple": "a green apple", "toy car": "a small red toy car",
     "mug_1": "a white ceramic mug", "mug_2": "a black ceramic mug",
     "tray": "a wooden serving tray", "bowl": "a blue plastic bowl"})  # fmt: skip
KITCHEN = scene(
    ["apple1", "apple2", "banana"], ["basket", "plate", "sponge"], "counter",
    {"apple1": "a shiny red apple", "apple2": "a green apple", "banana": "a ripe yellow banana",
     "basket": "a woven wicker basket", "plate": "a white ceramic plate",
     "sponge": "a yellow kitchen sponge"})  # fmt: skip
CANS = scene(["can1", "can2"], ["tray", "bottle"], "table",
             {"can1": "a red soda can", "can2": "a blue soda can", "tray": "a black plastic tray",
              "bottle": "a green glass bottle"})  # fmt: skip
CLEAN = scene(["sponge", "cloth"], ["bucket", "box"], "table",
              {"sponge": "a yellow sponge", "cloth": "a folded blue cloth"})
BLOCK = scene(["block"], ["box"], "table",
              {"block": "a red wooden block", "box": "a cardboard box"})
PENS = scene(["pen1", "pen2", "grey bowl"], ["notepad", "cup"], "table")  # EmbodiedGen's example
MARKER = scene(["marker"], ["mug", "notebook", "bowl"], "table")  # EmbodiedGen's example
MARKER_UR5 = scene(["marker", "bowl"], ["mug", "chair"], "table")
MARKER_CUP = scene(["marker", "cup"], ["plate", "spoon"], "counter")
MARKER_BOOK = scene(["marker", "book"], ["pen holder", "notepad"], "desk")
CUBE = scene(["rubik's cube"], ["pen", "cup", "toy car"], "shelf",
             tree={"room": [["shelf", "FLOOR"], ["franka", "IN"]],
                   "shelf": [[n, "INSIDE"] for n in ("rubik's cube", "pen", "cup", "toy car")]})
BASKET = scene(["banana", "mobile phone"], ["plate", "white basket"], "table")
ROPE = scene(["rope", "box"], ["magazine"], "chair")
DRAWER = scene(["seal tape", "plastic", "opened drawer"], ["scissors"], "counter")
PEN_MUG = scene(["pen"], ["mug", "notebook"], "desk")
PEN_CUP = scene(["pen"], ["cup", "notebook"], "table")
FRUIT = scene(["apple", "pear"], ["plate"], "table")
APPLES = scene(["apple1", "apple2"], ["plate"], "table")
SPOON = scene(["spoon"], ["plate"], "table")
LID = scene(["green lid"], ["red jar"], "desk")
PEN_TRAY = scene(["pen"], ["tray", "cup"], "table")
PLATE = scene(["plate"], ["cup"], "table")
LAMP = scene(["lamp"], ["book"], "desk")
PILLOW = scene(["pillow"], ["blanket"], "bed")
CUP = scene(["cup"], ["plate"], "table")
LAPTOP = scene(["laptop"], ["mouse"], "desk")
JAR = scene(["red jar", "lid"], ["spoon"], "table")
CLOTH = scene(["cloth"], ["box"], "table")
CHARGER = scene(["charger"], ["phone"], "desk")
JAR_DESK = scene(["jar"], ["book"], "desk")
CUBE_DESK = scene(["rubik's cube"], ["pen"], "desk")
MUG = scene(["mug"], ["plate"], "table")
ZH = scene(["苹果"], ["盘子"], "table", {"苹果": "a red apple", "盘子": "a white plate"})
CAFE = scene(["café_cup"], ["crème tray"], "table", {"café_cup": "a small espresso cup"})
DE = scene(["Würfel"], ["Schachtel"], "table",
           {"Würfel": "a wooden block", "Schachtel": "a cardboard box"})

R = REFUSE
TWO_APPLES = "place [red apple, green apple]"
CASES = [
    # EmbodiedGen's example task list, in its order
    ("Place the pen in the mug on the desk", PEN_MUG, ["place [pen] in mug"]),
    ("Get the pen from the table and put it inside the cup", PEN_CUP, ["place [pen] in cup"]),
    ("Put the fruit on the table on the plate", FRUIT, ["place [apple, pear] on plate"]),
    ("Put the apples on the table on the plate", APPLES, ["place [apple1, apple2] on plate"]),
    ("Put the pens in the grey bowl", PENS, ["place [pen1, pen2] in grey bowl"]),
    ("Put the spoon on the plate in the table", SPOON, ["place [spoon] on plate", R]),
    ("Put the green lid on the desk", LID, [R]),  # it stands on the desk already
    ("Put the pen on the tray", PEN_TRAY, ["place [pen] on tray"]),
    ("Move the plate forward", PLATE, ["move [plate] forward"]),
    ("Move the lamp to the left", LAMP, ["move [lamp] left"]),
    ("Move the pillow to the right", PILLOW, ["move [pillow] right"]),
    ("Pick up the cup and put on the middle of the table", CUP, [R]),
    ("Close the laptop", LAPTOP, [R]),
    ("Close the red jar with the lid on the table", JAR, [R]),
    ("Pick the cloth and shove it in the box", CLOTH, ["place [cloth] in box"]),
    ("Pick up the marker from the table and put it in the bowl", MARKER,
     ["place [marker] in bowl"]),
    ("Pick up the charger and move it slightly to the left", CHARGER, ["move [charger] left"]),
    ("Move the jar to the left side of the desk", JAR_DESK, ["move [jar] left"]),
    ("Pick the rubik's cube on the top of the desk", CUBE_DESK, ["pick [rubik's cube]"]),
    ("Move the mug to the right", MUG, ["move [mug] right"]),
    # EmbodiedGen's layout prompts' examples
    ("Pick up the marker from the table and put it in the bowl.", MARKER_UR5,
     ["place [marker] in bowl"]),
    ("Put the rubik's cube on the top of the shelf.", CUBE, ["place [rubik's cube] on shelf", R]),
    ("Remove all the objects from the white basket and put them on the table, robot piper.",
     BASKET, ["place [banana, mobile phone] on table", R]),
    ("Pick up the rope on the chair and put it in the box, robot franka.", ROPE,
     ["place [rope] in box"]),
    ("Pick up the seal tape and plastic from the counter and put them in the open drawer and "
     "close it.", DRAWER, [R]),
    ("Put the pens in the grey bowl.", PENS, ["place [pen1, pen2] in grey bowl"]),
    ("Put the marker on top of the book.", MARKER_BOOK, ["place [marker] on book"]),
    ("Put the marker in the cup on the counter.", MARKER_CUP, ["place [marker] in cup"]),
    # a desk with two mugs and two apples told apart by colour
    ("Put the pen in the bowl.", DESK, ["place [pen] in bowl"]),
    ("Place the pen into the white mug.", DESK, ["place [pen] in mug_1"]),
    ("Put the pen in the black mug, robot franka.", DESK, ["place [pen] in mug_2"]),
    ("Put the pen in the mug.", DESK, [R]),
    ("Please put the red apple on the tray.", DESK, ["place [red apple] on tray"]),
    ("Put the apple on the tray.", DESK, [R]),
    ("Put the apples on the tray.", DESK, [TWO_APPLES + " on tray"]),
    ("Put both apples in the bowl.", DESK, [TWO_APPLES + " in bowl"]),
    ("Move the toy car to the left.", DESK, ["move [toy car] left"]),
    ("Slide the toy car forward.", DESK, ["move [toy car] forward"]),
    ("Push the toy car 10 cm to the right.", DESK, ["move [toy car] right", R]),
    ("Move the toy car leftwards.", DESK, ["move [toy car] left"]),
    ("Drag the toy car to the right side of the desk.", DESK, ["move [toy car] right"]),
    ("Pick up the pen.", DESK, ["pick [pen]"]),
    ("Grab the pen then drop it into the bowl.", DESK, ["place [pen] in bowl"]),
    ("Pick up the pen and place it in the bowl.", DESK, ["place [pen] in bowl"]),
    ("Put the pen inside of the bowl.", DESK, ["place [pen] in bowl"]),
    ("Place the pen onto the top of the tray.", DESK, ["place [pen] on tray"]),
    ("Put the pen next to the bowl.", DESK, [R]),
    ("Put the pen in front of the tray.", DESK, [R]),
    ("Don't put the pen in the bowl.", DESK, [R]),
    ("Put the pen in the bowl and the red apple on the tray.", DESK, [R]),
    ("Move the toy car towards the bowl.", DESK, [R]),
    ("Put the stapler in the bowl.", DESK, [R]),
    ("Put the mug on the tray.", DESK, [R]),
    ("Put the white mug on the tray.", DESK, [R]),
    ("Transfer the green apple to the bowl.", DESK, ["place [green apple] in bowl", R]),
    ("Relocate the pen to the tray.", DESK, ["place [pen] on tray", R]),
    ("Deposit the red apple into the bowl.", DESK, ["place [red apple] in bowl"]),
    ("Carry the pen over to the tray and set it down.", DESK, ["place [pen] on tray", R]),
    ("Bring the green apple to the bowl.", DESK, ["place [green apple] in bowl", R]),
    ("Could you please place the pen in the bowl?", DESK, ["place [pen] in bowl"]),
    ("Kindly put the pen on the tray.", DESK, ["place [pen] on tray"]),
    ("The robot should put the pen in the bowl.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen on the tray, not in the bowl.", DESK, ["place [pen] on tray", R]),
    ("Put the pen in the bowl or on the tray.", DESK, [R]),
    ("Put the pen behind the bowl.", DESK, [R]),
    ("Put the pen under the tray.", DESK, [R]),
    ("Put the pen between the mugs.", DESK, [R]),
    ("Put the red apple in the bowl on the left.", DESK, [R]),
    ("Move the pen to the left of the bowl.", DESK, [R]),
    ("Push the toy car away from the bowl.", DESK, [R]),
    ("Nudge the toy car slightly to the right.", DESK, ["move [toy car] right"]),
    ("Move the toy car left and then forward.", DESK, [R]),
    ("Put the red apple in the bowl, then put the green apple in the bowl.", DESK,
     [TWO_APPLES + " in bowl", R]),
    ("Put the red apple and the green apple in the bowl.", DESK, [TWO_APPLES + " in bowl"]),
    ("Pick up the red apple.", DESK, ["pick [red apple]"]),
    ("Pick up the apple.", DESK, [R]),
    ("Lift the green apple onto the tray.", DESK, ["place [green apple] on tray"]),
    ("Place the toy car in the bowl.", DESK, ["place [toy car] in bowl"]),
    ("Put the pen back in the bowl.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen into the mug_1.", DESK, ["place [pen] in mug_1"]),
    ("Put the pen into mug 2.", DESK, ["place [pen] in mug_2", R]),
    ("Put the pen on the desk.", DESK, [R]),  # already there
    ("Put the bowl on the tray.", DESK, [R]),
    ("Put the pen in the bowl!", DESK, ["place [pen] in bowl"]),
    ("put the pen in the bowl", DESK, ["place [pen] in bowl"]),
    ("PUT THE PEN IN THE BOWL.", DESK, ["place [pen] in bowl"]),
    ("Place the ballpoint pen in the plastic bowl.", DESK, ["place [pen] in bowl"]),
    ("Put the pen in the blue bowl.", DESK, ["place [pen] in bowl"]),
    ("Put the pen in the red bowl.", DESK, [R]),
    ("Put the yellow apple in the bowl.", DESK, [R]),
    ("Put the pen in the bowl carefully.", DESK, ["place [pen] in bowl"]),
    ("Gently place the pen in the bowl.", DESK, ["place [pen] in bowl"]),
    ("Put the pen upside down in the bowl.", DESK, [R]),
    ("Put the pen in the bowl and hold it there.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen in the bowl twice.", DESK, [R]),
    ("Put the pen and the toy car on the tray.", DESK, ["place [pen, toy car] on tray"]),
    ("Put everything on the tray.", DESK, ["place [pen, red apple, green apple, toy car] on tray"]),
    ("Put all the apples into the bowl.", DESK, [TWO_APPLES + " in bowl"]),
    ("Put the pen near the bowl.", DESK, [R]),
    ("Put the pen beside the tray.", DESK, [R]),
    ("Put the pen on the left side of the tray.", DESK, [R]),
    ("Put the pen in the bowl and the mug.", DESK, [R]),
    ("Put the pen in the bowl, robot franka.", DESK, ["place [pen] in bowl"]),
    ("Move the pen into the bowl.", DESK, ["place [pen] in bowl"]),
    ("Move the toy car to the right by 10 centimeters.", DESK, ["move [toy car] right", R]),
    ("Push the toy car to the front.", DESK, ["move [toy car] forward", R]),
    ("Push the toy car back.", DESK, [R]),
    ("Move the toy car closer to the robot.", DESK, ["move [toy car] backward"]),
    ("Move the toy car away from you.", DESK, ["move [toy car] forward", R]),
    ("Put the red apple into the bowl then move the toy car left.", DESK, [R]),
    ("Take the pen out of the mug_1 and put it on the tray.", DESK, ["place [pen] on tray", R]),
    ("Put the pen on top of the red apple.", DESK, ["place [pen] on red apple", R]),
    ("Place the pen in the bowl which is on the desk.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen in the bowl if it is empty.", DESK, [R]),
    ("Without touching the mug, put the pen in the bowl.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen in the bowl. Then put the apple on the tray.", DESK, [R]),
    ("Stack the red apple on the green apple.", DESK, ["place [red apple] on green apple", R]),
    ("Sort the apples into the bowl.", DESK, [TWO_APPLES + " in bowl", R]),
    ("Throw the pen in the bowl.", DESK, ["place [pen] in bowl"]),
    ("Put pen in bowl", DESK, ["place [pen] in bowl"]),
    ("Put a pen in a bowl.", DESK, ["place [pen] in bowl"]),
    ("Put the pens in the bowl.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen in the bowl and the tray.", DESK, [R]),
    ("Put the apple in the bowl.", DESK, [R]),
    ("Put one apple in the bowl.", DESK, [R]),
    ("Put the pen in the bowl except the red apple.", DESK, [R]),
    # a kitchen counter: apples told apart in objs_desc only
    ("Put the apples in the basket.", KITCHEN, ["place [apple1, apple2] in basket"]),
    ("Put the red apple in the basket.", KITCHEN, ["place [apple1] in basket"]),
    ("Place the banana on the plate.", KITCHEN, ["place [banana] on plate"]),
    ("Put the fruit in the basket.", KITCHEN, ["place [apple1, apple2, banana] in basket"]),
    ("Put the yellow banana in the basket.", KITCHEN, ["place [banana] in basket"]),
    ("Put the yellow one in the basket.", KITCHEN, [R]),
    ("Put the sponge in the basket.", KITCHEN, [R]),
    ("Put apple1 in the basket.", KITCHEN, ["place [apple1] in basket"]),
    ("Put the banana and the apples in the basket.", KITCHEN,
     ["place [apple1, apple2, banana] in basket"]),
    ("Put the banana on the counter.", KITCHEN, [R]),
    ("Place the banana onto the plate, robot franka.", KITCHEN, ["place [banana] on plate"]),
    ("Put the banana in the basket instead of on the plate.", KITCHEN,
     ["place [banana] in basket", R]),
    ("Put the banana over the plate.", KITCHEN, [R]),
    ("Put the first apple in the basket.", KITCHEN, ["place [apple1] in basket", R]),
    ("Put one apple in the basket.", KITCHEN, [R]),
    ("Put an apple in the basket.", KITCHEN, [R]),
    ("Put two apples in the basket.", KITCHEN, ["place [apple1, apple2] in basket", R]),
    ("Put 3 apples in the basket.", KITCHEN, [R]),
    ("Put the banana in the basket and the apples on the plate.", KITCHEN, [R]),
    ("Put the banana to the basket.", KITCHEN, ["place [banana] in basket", R]),
    ("Put the banana inside the basket.", KITCHEN, ["place [banana] in basket"]),
    ("Drop the banana into the basket.", KITCHEN, ["place [banana] in basket"]),
    ("Put the banana in the basket on the counter.", KITCHEN, ["place [banana] in basket"]),
    ("Put the other apple in the basket.", KITCHEN, [R]),
    ("Put the apples except the green one in the basket.", KITCHEN, [R]),
    ("Put all apples but the green one in the basket.", KITCHEN, [R]),
    ("Put the bananas in the basket.", KITCHEN, ["place [banana] in basket", R]),
    ("Put the plate on the banana.", KITCHEN, [R]),
    ("Put the green apple in the basket and the red apple too.", KITCHEN,
     ["place [apple1, apple2] in basket", R]),
    # two cans
    ("Put both cans on the tray.", CANS, ["place [can1, can2] on tray"]),
    ("Put the cans onto the tray.", CANS, ["place [can1, can2] on tray"]),
    ("Put the red can on the tray.", CANS, ["place [can1] on tray"]),
    ("Put the can on the tray.", CANS, [R]),
    ("Put the cans on the tray next to each other.", CANS, ["place [can1, can2] on tray", R]),
    ("Stand the can upright on the tray.", CANS, [R]),
    ("Put the bottle on the tray.", CANS, [R]),
    ("Put the red soda can on the tray.", CANS, ["place [can1] on tray"]),
    ("Put can1 and can2 on the tray.", CANS, ["place [can1, can2] on tray"]),
    ("Put all cans on the tray.", CANS, ["place [can1, can2] on tray"]),
    ("Put the cans in the tray.", CANS, ["place [can1, can2] in tray"]),
    ("Put the green can on the tray.", CANS, [R]),
    ("Put the cans on the tray and the bottle.", CANS, [R]),
    ("Put the cans on the tray, one on top of the other.", CANS, [R]),
    ("Stack the cans on the tray.", CANS, ["place [can1, can2] on tray", R]),
    # cloths and sponges
    ("Wipe the table with the cloth.", CLEAN, [R]),
    ("Put the sponge and cloth in the box.", CLEAN, ["place [sponge, cloth] in box"]),
    ("Put the sponge on the cloth.", CLEAN, ["place [sponge] on cloth", R]),
    ("Fold the cloth.", CLEAN, [R]),
    ("Put the sponge in the bucket, then the cloth in the box.", CLEAN, [R]),
    ("Put the sponge into the box but not the cloth.", CLEAN, ["place [sponge] in box", R]),
    ("Put the sponge in the box, please.", CLEAN, ["place [sponge] in box"]),
    ("Put the blue cloth in the bucket.", CLEAN, ["place [cloth] in bucket"]),
    ("Put the yellow cloth in the bucket.", CLEAN, [R]),
    ("Squeeze the sponge over the bucket.", CLEAN, [R]),
    # one block, one box
    ("Move the block up.", BLOCK, [R]),
    ("Push the block to the edge of the table.", BLOCK, [R]),
    ("Push the block off the table.", BLOCK, [R]),
    ("Knock the block off the table.", BLOCK, [R]),
    ("Slide the block to the left by a few centimeters.", BLOCK, ["move [block] left", R]),
    ("Move the block to the box.", BLOCK, [R]),
    ("Put the block in the box.", BLOCK, ["place [block] in box"]),
    ("Put the block on the box.", BLOCK, ["place [block] on box"]),
    ("Put the block in the box upside down.", BLOCK, [R]),
    ("Rotate the block.", BLOCK, [R]),
    ("Push the block forward and to the left.", BLOCK, [R]),
    ("Push the block diagonally.", BLOCK, [R]),
    ("Move the block to the left and put it in the box.", BLOCK, [R]),
    ("Move the block left 5 cm.", BLOCK, ["move [block] left", R]),
    ("Place the block to the left of the box.", BLOCK, [R]),
    ("Put the block at the center of the table.", BLOCK, [R]),
    ("Pick up the block and hold it.", BLOCK, ["pick [block]", R]),
    ("Pick up the box.", BLOCK, [R]),
    ("Give me the block.", BLOCK, [R]),
    ("Hand the block to the person.", BLOCK, [R]),
    ("Put the block in the box, robot franka", BLOCK, ["place [block] in box"]),
    ("Put the red block in the box.", BLOCK, ["place [block] in box"]),
    ("Put the blue block in the box.", BLOCK, [R]),
    ("Put the block into the box and close the box.", BLOCK, [R]),
    ("Put the block in the box and then push the box to the left.", BLOCK, [R]),
    ("Pick up the block from the box.", BLOCK, ["pick [block]", R]),
    ("Push the block to the right, robot franka.", BLOCK, ["move [block] right"]),
    ("Move the block right a little.", BLOCK, ["move [block] right"]),
    ("Shift the block rightward.", BLOCK, ["move [block] right"]),
    ("Move the block to your left.", BLOCK, ["move [block] left", R]),
    # node names in other scripts, with underscores and accents
    ("Put the apple on the plate.", ZH, ["place [苹果] on 盘子"]),
    ("Put the 苹果 on the 盘子.", ZH, ["place [苹果] on 盘子"]),
    ("Put the café cup on the crème tray.", CAFE, ["place [café_cup] on crème tray"]),
    ("Move the café cup to the right.", CAFE, ["move [café_cup] right"]),
    ("Put the espresso cup on the tray.", CAFE, ["place [café_cup] on crème tray"]),
    ("Put the block in the box.", DE, ["place [Würfel] in Schachtel"]),
    ("Put the Würfel in the Schachtel.", DE, ["place [Würfel] in Schachtel"]),
    # a second pass: the phrasings that stress the reader's joints
    ("Pick and place the pen in the bowl.", DESK, ["place [pen] in bowl"]),
    ("Pick-and-place the pen into the bowl.", DESK, ["place [pen] in bowl"]),
    ("Pick up and place the red apple onto the tray.", DESK, ["place [red apple] on tray"]),
    ("Robot, put the pen in the bowl.", DESK, ["place [pen] in bowl"]),
    ("Franka: place the pen in the bowl.", DESK, ["place [pen] in bowl"]),
    ("Could you please place the pen in the bowl?", DESK, ["place [pen] in bowl"]),
    ("Put the pen in the bowl, then lift it.", DESK, [R]),
    ("Put the pen in the bowl and pick it up again.", DESK, [R]),
    ("Put the pen with the red apple in the bowl.", DESK,
     ["place [pen, red apple] in bowl", R]),
    ("Put the pen in the bowl with the red apple.", DESK, [R]),
    ("Put some apples in the bowl.", DESK, [R]),
    ("Put the two apples in the bowl.", DESK, [TWO_APPLES + " in bowl"]),
    ("Put three apples in the bowl.", DESK, [R]),
    ("Put 2 apples in the bowl.", DESK, [TWO_APPLES + " in bowl", R]),
    ("Move the toy car to my left.", DESK, [R]),
    ("Move the toy car to your left.", DESK, ["move [toy car] left", R]),
    ("Move the toy car to the robot's left.", DESK, ["move [toy car] left", R]),
    ("Pull the toy car towards the robot.", DESK, ["move [toy car] backward"]),
    ("Pull the toy car to the left.", DESK, ["move [toy car] left"]),
    ("Roll the toy car forward.", DESK, ["move [toy car] forward"]),
    ("Shove the toy car to the right.", DESK, ["move [toy car] right"]),
    ("Relocate the pen into the bowl.", DESK, ["place [pen] in bowl"]),
    ("Carry the pen into the bowl.", DESK, ["place [pen] in bowl"]),
    ("Bring the pen onto the tray.", DESK, ["place [pen] on tray"]),
    ("Lower the pen into the bowl.", DESK, ["place [pen] in bowl"]),
    ("Pack the apples into the bowl.", DESK, [TWO_APPLES + " in bowl"]),
    ("Slide the toy car over to the left.", DESK, ["move [toy car] left", R]),
    ("Put the pen in the bowl using the gripper.", DESK, [R]),
    ("Place the pen into the bowl, the apple onto the tray.", DESK, [R]),
    ("Put the pen in both mugs.", DESK, [R]),
    ("Put the pen in a mug.", DESK, [R]),
    ("Put the pen in the left mug.", DESK, [R]),
    ("Put the blue pen in the bowl.", DESK, [R]),
    ("Remove the pen from the tray.", DESK, ["pick [pen]", R]),
    ("Put the pen in the bowl;", DESK, ["place [pen] in bowl", R]),
    ("Move the toy car 10cm to the left.", DESK, ["move [toy car] left", R]),
    ("Move the toy car 0.1 m to the left.", DESK, ["move [toy car] left", R]),
    ("Move the toy car ten centimeters to the left.", DESK, ["move [toy car] left", R]),
    ("Move the toy car further left.", DESK, [R]),
    ("Move the toy car to the far left.", DESK, [R]),
    ("Move the toy car left, then right.", DESK, [R]),
    ("Move the toy car right and the pen left.", DESK, [R]),
    ("Move the pen and the toy car to the left.", DESK, ["move [pen, toy car] left"]),
    ("Move the toy car to the left of the red apple.", DESK, [R]),
    ("Move the toy car to the apple's left.", DESK, [R]),
    ("Move the toy car left of the bowl.", DESK, [R]),
    ("Put the pen in the bowl that is on the desk.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen on the desk into the bowl.", DESK, ["place [pen] in bowl"]),
    ("Put the pen in the bowl on the tray.", DESK, [R]),
    ("Put the pen in the bowl so that it stands.", DESK, [R]),
    ("Put the pen in the bowl to tidy up the desk.", DESK, ["place [pen] in bowl", R]),
    ("The pen goes in the bowl.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen in the mug_2 and the bowl.", DESK, [R]),
    ("Put the pen into the second mug.", DESK, [R]),
    ("Put the pen in the mug 1.", DESK, ["place [pen] in mug_1", R]),
    ("Put the pen in mug3.", DESK, [R]),
    ("Grab the red apple and drop it in the blue bowl.", DESK, ["place [red apple] in bowl"]),
    ("Take the green apple and put it on top of the tray.", DESK, ["place [green apple] on tray"]),
    ("Pick up the toy car and move it to the right.", DESK, ["move [toy car] right"]),
    ("Pick up the toy car and move it onto the tray.", DESK, ["place [toy car] on tray"]),
    ("Pick up the pen from the desk.", DESK, ["pick [pen]"]),
    ("Pick up the pen and the toy car.", DESK, [R]),
    ("Lift the pen above the bowl.", DESK, [R]),
    ("Hold the pen over the bowl.", DESK, [R]),
    ("Put the pen down on the tray.", DESK, ["place [pen] on tray"]),
    ("Set the pen down inside the bowl.", DESK, ["place [pen] in bowl"]),
    ("Put away the pen in the bowl.", DESK, ["place [pen] in bowl", R]),
    ("Place the pen gently and precisely into the bowl.", DESK, ["place [pen] in bowl"]),
    ("Put the apple and the pen in the bowl.", DESK, [R]),
    ("Put the apples and the pen in the bowl.", DESK,
     ["place [pen, red apple, green apple] in bowl"]),
    ("Put the pen in the bowl and the tray on the desk.", DESK, [R]),
    ("Put the pen in the bowl, the bowl on the tray.", DESK, [R]),
    ("Put the pen in the mug or the bowl.", DESK, [R]),
    ("Put the pen in the tray's bowl.", DESK, [R]),
    ("Put the pen into the bowl of the tray.", DESK, [R]),
    ("Put the pen in the bowl of fruit.", DESK, [R]),
    ("Put the toy car on the tray and push it to the left.", DESK, [R]),
    ("Push the tray to the left.", DESK, [R]),
    ("Place the pen in the bowl and the apple.", DESK, [R]),
    ("Put every apple in the bowl.", DESK, [TWO_APPLES + " in bowl"]),
    ("Put each apple into the bowl.", DESK, [TWO_APPLES + " in bowl"]),
    ("Put all objects on the tray.", DESK,
     ["place [pen, red apple, green apple, toy car] on tray"]),
    ("Put all the fruit in the bowl.", DESK, [TWO_APPLES + " in bowl"]),
    ("Put the fruit on the tray except the green apple.", DESK, [R]),
    ("Put only the pen in the bowl.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen and marker in the bowl.", DESK, [R]),
    ("Put the red apple on the green apple.", DESK, ["place [red apple] on green apple", R]),
    ("Put the red apple in itself.", DESK, [R]),
    ("Put the pen in the pen.", DESK, [R]),
    ("Put the bowl in the bowl.", DESK, [R]),
    ("Put the pen in the bowl in the bowl.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen.", DESK, [R]),
    ("Put in the bowl.", DESK, [R]),
    ("Put", DESK, [R]),
    ("", DESK, ["pick [pen]", R]),
    ("...", DESK, [R]),
    ("the pen in the bowl", DESK, [R]),
    ("Put the pen in the bowl robot franka", DESK, ["place [pen] in bowl"]),
    ("Put the pen in the bowl (robot: franka).", DESK, ["place [pen] in bowl", R]),
    ("Put the pen in the bowl, robot ur5.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen in the bowl, with the robot franka.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen in the bowl quickly, robot franka!", DESK, ["place [pen] in bowl"]),
    ("Put the pen in the bowl on the left side of the desk.", DESK, [R]),
    ("Put the pen on the near side of the tray.", DESK, [R]),
    ("Put the pen in the center of the tray.", DESK, [R]),
    ("Put the pen at the bottom of the bowl.", DESK, [R]),
    ("Put the pen into the bottom of the bowl.", DESK, ["place [pen] in bowl", R]),
    ("Put the pen on the surface of the tray.", DESK, ["place [pen] on tray", R]),
    ("Put the pen on the tray's top.", DESK, ["place [pen] on tray", R]),
    ("Place the red apple onto the top of the bowl.", DESK, ["place [red apple] on bowl", R]),
    ("Put the pen inside the tray.", DESK, ["place [pen] in tray"]),
    ("Tidy the desk.", DESK, [R]),
    ("Put the bananas in the basket.", KITCHEN, ["place [banana] in basket", R]),
    ("Put the banana in the basket and the apples as well.", KITCHEN,
     ["place [apple1, apple2, banana] in basket", R]),
    ("Put both the apples and the banana in the basket.", KITCHEN,
     ["place [apple1, apple2, banana] in basket"]),
    ("Put the two apples on the plate, robot franka.", KITCHEN,
     ["place [apple1, apple2] on plate"]),
    ("Put the shiny apple on the plate.", KITCHEN, ["place [apple1] on plate"]),
    ("Put the ripe banana in the wicker basket.", KITCHEN, ["place [banana] in basket"]),
    ("Put the plastic basket on the plate.", KITCHEN, [R]),
    ("Put the apple 2 in the basket.", KITCHEN, ["place [apple2] in basket"]),
    ("Put apple3 in the basket.", KITCHEN, [R]),
    ("Put the pear in the basket.", KITCHEN, [R]),
    ("Put the fruit except the banana in the basket.", KITCHEN, [R]),
    ("Put the fruit apart from the banana in the basket.", KITCHEN, [R]),
    ("Put the fruit other than the banana in the basket.", KITCHEN, [R]),
    ("Put the fruit in the basket apart from the banana.", KITCHEN, [R]),
    ("Put the remaining fruit in the basket.", KITCHEN,
     [R, "place [apple1, apple2, banana] in basket"]),
    ("Put half of the apples in the basket.", KITCHEN, [R]),
    ("Put most of the fruit in the basket.", KITCHEN, [R]),
    ("Put one of the apples in the basket.", KITCHEN, [R]),
    ("Put a few apples in the basket.", KITCHEN, [R]),
    ("Put many apples in the basket.", KITCHEN, [R]),
    ("Put any apple in the basket.", KITCHEN, [R]),
    ("Put the biggest apple in the basket.", KITCHEN, [R]),
    ("Put the banana in the basket, leaving the apples.", KITCHEN, [R, "place [banana] in basket"]),
    ("Put the cans on the tray one by one.", CANS, [R, "place [can1, can2] on tray"]),
    ("Put the red can on the tray first, then the blue can.", CANS,
     [R, "place [can1, can2] on tray"]),
    ("Put the red can on top of the blue can.", CANS, [R, "place [can1] on can2"]),
    ("Put the cans on the tray upright.", CANS, [R]),
    ("Put the soda cans on the tray.", CANS, ["place [can1, can2] on tray"]),
    ("Put the can of soda on the tray.", CANS, [R]),
    ("Put the blue and red cans on the tray.", CANS, ["place [can1, can2] on tray", R]),
    ("Put the red and the blue can on the tray.", CANS, ["place [can1, can2] on tray", R]),
    ("Put the cans on the plastic tray.", CANS, ["place [can1, can2] on tray"]),
    ("Put the cans on the wooden tray.", CANS, [R]),
    ("Place both soda cans onto the black tray, robot franka.", CANS,
     ["place [can1, can2] on tray"]),
    ("Push the cans to the left.", CANS, ["move [can1, can2] left"]),
    ("Push the block towards the left.", BLOCK, ["move [block] left"]),
    ("Push the block towards the box.", BLOCK, [R]),
    ("Push the block into the box.", BLOCK, ["place [block] in box"]),
    ("Pull the block out of the box.", BLOCK, [R]),
    ("Take the block out of the box.", BLOCK, ["pick [block]", R]),
    ("Move the block away.", BLOCK, ["move [block] forward", R]),
    ("Move the block away from the box.", BLOCK, [R]),
    ("Move the block back to the box.", BLOCK, [R]),
    ("Put the block back.", BLOCK, [R]),
    ("Put the block back in the box.", BLOCK, ["place [block] in box", R]),
    ("Move the block to the right side of the table.", BLOCK, ["move [block] right"]),
    ("Move the block to the right side of the box.", BLOCK, [R]),
    ("Move the block right of the box.", BLOCK, [R]),
    ("Move the block to the right, next to the box.", BLOCK, [R]),
    ("Move the block to the right until it touches the box.", BLOCK, [R]),
    ("Move the block forward a bit.", BLOCK, ["move [block] forward"]),
    ("Move the block forwards slightly.", BLOCK, ["move [block] forward"]),
    ("Move the block backwards.", BLOCK, ["move [block] backward"]),
    ("Move the block towards you.", BLOCK, ["move [block] backward"]),
    ("Move the block towards me.", BLOCK, [R, "move [block] backward"]),
    ("Move the block north.", BLOCK, [R]),
    ("Move the block clockwise.", BLOCK, [R]),
    ("Flip the block.", BLOCK, [R]),
    ("Stack the block on the box.", BLOCK, ["place [block] on box"]),
    ("Insert the block into the box.", BLOCK, ["place [block] in box"]),
    ("Drop the block in the box from above.", BLOCK, [R, "place [block] in box"]),
    ("Put the block in the box on the table.", BLOCK, ["place [block] in box"]),
    ("Put the block on the table.", BLOCK, [R]),
    ("Put the block on the floor.", BLOCK, [R]),
    ("Put the block in the drawer.", BLOCK, [R]),
    ("Put the block in the box and the box on the table.", BLOCK, [R]),
    ("Put the wooden block in the cardboard box.", BLOCK, ["place [block] in box"]),
    ("Put the metal block in the box.", BLOCK, [R]),
    ("Put the block in the metal box.", BLOCK, [R]),
    ("Put the cube in the box.", BLOCK, [R]),
    ("Put the blocks in the box.", BLOCK, ["place [block] in box", R]),
    ("Put the box in the box.", BLOCK, [R]),
    ("Put the block in the box in the box.", BLOCK, ["place [block] in box", R]),
    ("Put the block in the box and close it.", BLOCK, [R]),
    ("Put the block in the box, then shake it.", BLOCK, [R]),
    ("Place the block inside the box and leave it there.", BLOCK, [R, "place [block] in box"]),
]  # fmt: skip


def reading(sentence, layout):
    """The task read from ``sentence`` as ``layout validate`` prints it, or REFUSE."""
    relation = dict(layout["relation"], task_desc=sentence)
    obj = SimpleNamespace(**dict(layout, relation=relation))
    try:
        return resolve_task(obj, F).describe()
    except LayoutError as e:
        text = str(e)
        assert len(e.problems) == 1 and "\n" not in text, text
        assert text.startswith(F + ": ") and " ".join(sentence.split()) in text, text
        return REFUSE


def _same(got, want):
    """The same reading, the movers in any order."""
    if REFUSE in (got, want):
        return got == want
    head, _, tail = got.partition("]")
    whead, _, wtail = want.partition("]")
    return tail == wtail and head.split("[")[0] == whead.split("[")[0] and sorted(
        head.split("[")[1].split(", ")) == sorted(whead.split("[")[1].split(", "))


@pytest.mark.parametrize("sentence, layout, accepted", CASES,
                         ids=[f"{i}:{c[0][:50]}" for i, c in enumerate(CASES)])  # fmt: skip
def test_sentence_is_read_as_a_person_reads_it_or_refused(sentence, layout, accepted):
    got = reading(sentence, layout)
    assert any(_same(got, a) for a in accepted), f"{sentence!r} -> {got}"
