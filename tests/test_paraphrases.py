"""Paraphrases of every skill (issue 14 item 3) and the refusals of what is not one skill on one object.

The table below is written by hand: verb synonyms, polite wrappers, missing or other determiners, case
and whitespace, and two-clause "pick up X and put it ..." forms, for every skill of templates.yaml. X
must come out exactly as the object words (colours and multiword names included).
"""

from __future__ import annotations

import pytest

from abm.language.instruction import (
    InstructionError,
    MultiStepInstructionError,
    RewritingParser,
    TemplateParser,
    decompose_instruction,
    load_templates,
)

PLATE = "put X in the plate"
TARGET = "put X on the target"
TOP = "put X on the top shelf"
BOTTOM = "put X on the bottom shelf"
RACK = "put X in the wine rack"
WATER = "water the plant with X"
CLOSE = "close X"
RING = "put the ring on X"
PAN = "take X off the frypan"
PUT_IN = "put X in Y"  # two targets: decompose_instruction gives X (the parser's `second` is Y)

PARAPHRASES: list[tuple[str, str, str]] = [
    # put X in the plate
    ("grasp the tomato soup can and put it in the plate", PLATE, "tomato soup can"),
    ("Could you set the cream cheese onto the plate?", PLATE, "cream cheese"),
    ("take that ketchup and drop it in this plate", PLATE, "ketchup"),
    ("PUT   Ketchup   IN   Plate", PLATE, "ketchup"),
    ("hey robot, lay the bbq sauce on top of the plate.", PLATE, "bbq sauce"),
    ("I need you to carry the milk over to the plate", PLATE, "milk"),
    ("lift the chocolate pudding up and then put it down in the plate", PLATE, "chocolate pudding"),
    ("pick the popcorn up then place it into the plate, thanks", PLATE, "popcorn"),
    ("grab the mac and cheese and put it on the plate", PLATE, "mac and cheese"),
    ("put the red block inside the plate for me", PLATE, "red block"),
    ("take hold of the orange juice and set it on the plate", PLATE, "orange juice"),
    ("grab the ketchup, then place it neatly in the plate", PLATE, "ketchup"),
    # put X on the target
    ("pick up the red block and put it on the target", TARGET, "red block"),
    ("can you please grab the purple block and place it on the target?", TARGET, "purple block"),
    ("Take the pink block and drop it onto the target area", TARGET, "pink block"),
    ("move that cyan block toward the target", TARGET, "cyan block"),
    ("i'd like you to stack a yellow block on top of the target!", TARGET, "yellow block"),
    ("get the salad dressing then put it on the target spot", TARGET, "salad dressing"),
    ("deliver the alphabet soup to the target please", TARGET, "alphabet soup"),
    ("set green block on target", TARGET, "green block"),
    # put X on the top shelf / bottom shelf
    ("lift the milk and put it on the top shelf", TOP, "milk"),
    ("could you store the tomato sauce on the highest shelf", TOP, "tomato sauce"),
    ("please carry the cookies to the top shelf", TOP, "cookies"),
    ("Place the alphabet soup in the upper shelf.", TOP, "alphabet soup"),
    ("set the butter on the bottom shelf", BOTTOM, "butter"),
    ("grab the bbq sauce and stack it on the lowest shelf", BOTTOM, "bbq sauce"),
    ("put chocolate pudding onto lower shelf now", BOTTOM, "chocolate pudding"),
    ("gently put the egg on the upper shelf", TOP, "egg"),
    # put X in the wine rack
    ("pick up the white bottle and place it in the wine rack", RACK, "white bottle"),
    ("would you put a brown bottle into the bottle rack", RACK, "brown bottle"),
    ("move the blue bottle to the wine rack, please", RACK, "blue bottle"),
    ("set the wine bottle inside the rack", RACK, "wine bottle"),
    # water the plant with X
    ("water the plants using the porcelain mug", WATER, "porcelain mug"),
    ("grab the moka pot and water the plant with it", WATER, "moka pot"),
    ("pick up the white mug and use it to water the flowers", WATER, "white mug"),
    ("tilt the red mug over the plant", WATER, "red mug"),
    ("pour water on the plant with the red watering can", WATER, "red watering can"),
    ("please use the moka pot to water the plant for me", WATER, "moka pot"),
    # close X
    ("shut that purple jar!", CLOSE, "purple jar"),
    ("could you screw the lid onto the orange jar", CLOSE, "orange jar"),
    ("Seal the Cyan Jar, please.", CLOSE, "cyan jar"),
    ("put the cap back on the pink jar", CLOSE, "pink jar"),
    ("close the lid of the yellow jar", CLOSE, "yellow jar"),
    ("cover the red jar with a lid", CLOSE, "red jar"),
    # put the ring on X (X is the peg, as in the single-clause template)
    ("pick up the ring and put it on the cyan peg", RING, "cyan peg"),
    ("grab the hoop and thread it onto the orange peg", RING, "orange peg"),
    ("hang the ring over the purple peg please", RING, "purple peg"),
    ("place ring around blue peg", RING, "blue peg"),
    ("take the ring and then drop it down onto the yellow peg", RING, "yellow peg"),
    # take X off the frypan
    ("lift the popcorn out of the frying pan", PAN, "popcorn"),
    ("can you get the cookies off of the pan?", PAN, "cookies"),
    ("grab the chocolate pudding away from the skillet", PAN, "chocolate pudding"),
    ("move the alphabet soup off the frypan", PAN, "alphabet soup"),
    ("take the cream cheese out of the fry pan and put it on the table", PAN, "cream cheese"),
    ("remove the butter from the pan and set it beside the pan", PAN, "butter"),
    ("clear the frypan of the butter", PAN, "butter"),
    # put X in Y (put_in_container)
    ("put the butter in the white bowl", PUT_IN, "butter"),
    ("could you drop the red block into the wooden tray, please", PUT_IN, "red block"),
    ("pick up the cream cheese and place it inside the basket", PUT_IN, "cream cheese"),
    ("bring the cookies to the red basket", PUT_IN, "cookies"),
]


def test_paraphrase_table_covers_every_skill():
    assert len(PARAPHRASES) >= 50
    assert {skill for _, skill, _ in PARAPHRASES} == {t.skill for t in load_templates().skills}
    assert len({text for text, _, _ in PARAPHRASES}) == len(PARAPHRASES)


@pytest.mark.parametrize(("instruction", "skill", "target"), PARAPHRASES)
def test_paraphrase(instruction, skill, target):
    assert decompose_instruction(instruction) == (target, skill)


def test_parsing_is_deterministic():
    parser = TemplateParser()
    first = [parser.parse(text) for text, _, _ in PARAPHRASES]
    assert [TemplateParser().parse(text) for text, _, _ in PARAPHRASES] == first


def test_every_example_in_templates_parses_to_its_skill():
    parser = TemplateParser()
    for template in parser.templates.skills:
        assert template.examples, template.skill
        for example in template.examples:
            assert parser.parse(example).skill == template.skill, example


REFUSALS: list[tuple[str, type[InstructionError], list[str]]] = [
    # several steps, one of them unknown
    (
        "pick up the block, then open the drawer and put it inside",
        MultiStepInstructionError,
        ["asks for 3 steps", "'open drawer'", "one skill per instruction"],
    ),
    ("close the red jar and afterwards dance", MultiStepInstructionError, ["asks for 2 steps", "'dance'"]),
    # several known steps: listed, to be given one at a time
    (
        "pick up the red block and put it on the target and then close the blue jar",
        MultiStepInstructionError,
        ["asks for 2 steps", "'put the red block on the target', then 'close the blue jar'"],
    ),
    (
        "take the steak off the pan and put it in the plate",
        MultiStepInstructionError,
        ["asks for 2 steps", "'take steak off the frypan'"],
    ),
    # several or unspecified objects
    ("stack all blocks", MultiStepInstructionError, ["'all' asks for several or unspecified objects"]),
    ("put every jar on the target", MultiStepInstructionError, ["'every'"]),
    (
        "put the red block and the blue block on the target",
        MultiStepInstructionError,
        ["'red block and blue block' names several objects"],
    ),
    # no object named
    ("put it in the plate", InstructionError, ["'it' does not say which object", "'put the tomato in the plate'"]),
    # a grasp without a goal
    (
        "pick up the red block",
        InstructionError,
        ["picking up 'red block'", "'put the red block in the plate'", "'put the red block on the target'"],
    ),
    # gibberish and unknown skills
    ("asdf qwer zxcv", InstructionError, ["no skill template matches", "'asdf qwer zxcv'"]),
    ("open the drawer", InstructionError, ["no skill template matches"]),
    ("put the tomato next to the plate", InstructionError, ["no skill template matches"]),
    ("please, thanks!", InstructionError, ["nothing is left"]),
]


def test_refusal_table_is_large_enough():
    assert len(REFUSALS) >= 8


@pytest.mark.parametrize(("instruction", "kind", "fragments"), REFUSALS)
def test_refusal_message(instruction, kind, fragments):
    with pytest.raises(kind) as err:
        decompose_instruction(instruction)
    message = str(err.value)
    assert repr(instruction) in message  # names what was not understood
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    # lists accepted phrasings and the known skills
    for phrasing in ("'put the tomato in the plate'", "'close the red jar'", "'take the steak off the frypan'"):
        assert phrasing in message
    assert "put X on the target" in message and "pick up the red block and put it on the target" in message
    if kind is MultiStepInstructionError:
        assert "one instruction after the other" in message
    else:
        assert "RewritingParser" in message and "language-model rewriter" in message


def test_only_single_step_refusals_go_to_the_rewriter():
    calls: list[str] = []

    def rewrite(text: str) -> str:
        calls.append(text)
        return "put the ketchup in the plate"

    parser = RewritingParser(rewrite)
    assert parser.parse("pick up the red block").target == "ketchup"  # refused by templates: rewritten
    assert calls == ["pick up the red block"]
    with pytest.raises(MultiStepInstructionError):
        parser.parse("stack all blocks")  # a rewriter would drop objects
    assert calls == ["pick up the red block"]


def test_object_names_keep_and_and_verbs():
    assert decompose_instruction("put the salt and pepper in the plate") == ("salt and pepper", PLATE)
    assert decompose_instruction("put the water bottle in the rack") == ("water bottle", RACK)
    assert decompose_instruction("pick up the cover and put it in the plate") == ("cover", PLATE)


def test_user_templates_use_and_extend_builtin_synonyms(tmp_path):
    path = tmp_path / "extra.yaml"
    path.write_text(
        "synonyms:\n  put: [shove]\n"
        "skills:\n  - skill: put X in the drawer\n    patterns: ['<put> {X} <in> drawer']\n"
        "    examples: [put the spoon in the drawer]\n"
    )
    parser = TemplateParser.from_files(path)
    assert parser.parse("grab the spoon and place it in the drawer").skill == "put X in the drawer"
    assert parser.parse("shove the spoon into the drawer").target == "spoon"
    assert parser.parse("shove the tomato onto the plate").skill == PLATE  # group extended for built-ins too
    inline = TemplateParser().with_templates({"skills": [{"skill": "push X", "patterns": ["<put> {X} away"]}]})
    assert inline.parse("could you move the red block away").skill == "push X"


def test_bad_synonyms_are_reported(tmp_path):
    with pytest.raises(ValueError, match="unknown synonym group <shove>"):
        TemplateParser().with_templates({"skills": [{"skill": "push X", "patterns": ["<shove> {X}"]}]})
    bad = tmp_path / "bad.yaml"
    bad.write_text("synonyms:\n  near: [on, by]\nskills: []\n")  # bare `on` is a YAML boolean
    with pytest.raises(ValueError, match="quote them"):
        load_templates(bad)
