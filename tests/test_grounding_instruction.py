"""Instruction decomposition: templates of all ten tasks, robustness, extension, errors."""

from __future__ import annotations

import pytest

from abm.errors import ConfigError
from abm.language.instruction import (
    InstructionError,
    InstructionParser,
    RewritingParser,
    TemplateParser,
    clip_prompt,
    decompose_instruction,
    load_templates,
    normalize_instruction,
)

CASES = [
    # place_food
    ("put the tomato in the plate", "tomato", "put X in the plate"),
    ("put the ketchup in the plate", "ketchup", "put X in the plate"),
    ("Put the Cream Cheese in the plate.", "cream cheese", "put X in the plate"),
    ("please put the bbq sauce in the plate", "bbq sauce", "put X in the plate"),
    ("put the mac and cheese into a plate!", "mac and cheese", "put X in the plate"),
    ("Could you put an orange juice in the plate?", "orange juice", "put X in the plate"),
    ("place the alphabet soup on the plate", "alphabet soup", "put X in the plate"),
    ("put the onion in the plate", "onion", "put X in the plate"),
    # pick_block
    ("put the red block on the target", "red block", "put X on the target"),
    ("Put the BLUE block on the target", "blue block", "put X on the target"),
    ("put the green block onto the target please", "green block", "put X on the target"),
    ("stack the yellow block on top of the target", "yellow block", "put X on the target"),
    ("put a purple block on a target", "purple block", "put X on the target"),
    # put_in_shelf
    ("put the milk on the top shelf", "milk", "put X on the top shelf"),
    ("put the butter on the bottom shelf", "butter", "put X on the bottom shelf"),
    ("Can you please put the chocolate pudding on the bottom shelf?", "chocolate pudding",
     "put X on the bottom shelf"),
    ("put the popcorn in the top shelf", "popcorn", "put X on the top shelf"),
    # place_wine
    ("put the wine bottle in the wine rack", "wine bottle", "put X in the wine rack"),
    ("put the green bottle in the wine rack", "green bottle", "put X in the wine rack"),
    ("place the beer bottle into the rack", "beer bottle", "put X in the wine rack"),
    # water_plants
    ("water the plant with the red mug", "red mug", "water the plant with X"),
    ("Water the plant with the white kettle.", "white kettle", "water the plant with X"),
    ("water the plants using the blue cup", "blue cup", "water the plant with X"),
    # close_jar
    ("close the red jar", "red jar", "close X"),
    ("Close the navy jar.", "navy jar", "close X"),
    ("please close the olive jar", "olive jar", "close X"),
    ("shut the blue jar", "blue jar", "close X"),
    # insert_peg
    ("put the ring on the green peg", "green peg", "put the ring on X"),
    ("put the ring on the magenta peg", "magenta peg", "put the ring on X"),
    ("Put the ring onto the cyan peg!", "cyan peg", "put the ring on X"),
    # take_off_pan
    ("take the steak off the frypan", "steak", "take X off the frypan"),
    ("take the chicken off the frypan", "chicken", "take X off the frypan"),
    ("Take the sausage off the frying pan.", "sausage", "take X off the frypan"),
    ("remove the fish from the pan", "fish", "take X off the frypan"),
    # compositional: place_block_in_plate -> trained skill of place_food
    ("put the red block in the plate", "red block", "put X in the plate"),
    ("put the orange block in the plate", "orange block", "put X in the plate"),
    # compositional: pick_food_to_target -> trained skill of pick_block
    ("put the ketchup on the target", "ketchup", "put X on the target"),
    ("put the cream cheese on the target", "cream cheese", "put X on the target"),
    ("put the tomato sauce on the target", "tomato sauce", "put X on the target"),
    # whitespace, punctuation, polite words
    ("  put   the   salad dressing   in the plate  ", "salad dressing", "put X in the plate"),
    ("Robot, could you please put the butter in the plate, thanks!", "butter", "put X in the plate"),
    ("I want you to close the teal jar now", "teal jar", "close X"),
    ("put the ring on the target", "ring", "put X on the target"),
]


def test_case_table_is_large_enough():
    assert len(CASES) >= 40


@pytest.mark.parametrize(("instruction", "target", "skill"), CASES)
def test_decompose(instruction, target, skill):
    assert decompose_instruction(instruction) == (target, skill)


def test_no_match_lists_known_skills():
    with pytest.raises(InstructionError) as err:
        decompose_instruction("dance the robot dance")
    message = str(err.value)
    assert "dance the robot dance" in message
    for skill in ("put X in the plate", "close X", "take X off the frypan"):
        assert skill in message
    assert isinstance(err.value, ValueError)


@pytest.mark.parametrize("bad", ["", "   ", "please", "put the in the plate"])
def test_degenerate_instructions_fail(bad):
    with pytest.raises(InstructionError):
        decompose_instruction(bad)


def test_non_string_is_rejected():
    with pytest.raises(TypeError):
        decompose_instruction(42)  # type: ignore[arg-type]


def test_clip_prompt_article():
    assert clip_prompt("tomato") == "a photo of a tomato"
    assert clip_prompt("orange juice") == "a photo of an orange juice"
    assert clip_prompt("Apple") == "a photo of an Apple"
    assert clip_prompt("red block") == "a photo of a red block"
    with pytest.raises(ValueError):
        clip_prompt(" ")


def test_parsed_instruction_fields():
    parsed = TemplateParser().parse("put the egg on the top shelf")
    assert parsed.target == "egg" and parsed.prompt == "a photo of an egg"
    assert "put_in_shelf" in parsed.tasks
    assert isinstance(TemplateParser(), InstructionParser)


def test_normalize_instruction():
    assert normalize_instruction("Please, put the Cream-Cheese in a plate!", ["please"]) == \
        "put cream-cheese in plate"


def test_builtin_skills_cover_all_tasks():
    tasks = {t for s in load_templates().skills for t in s.tasks}
    assert tasks >= {"place_food", "pick_block", "put_in_shelf", "place_wine", "water_plants", "close_jar",
                     "insert_peg", "take_off_pan", "place_block_in_plate", "pick_food_to_target"}


def test_user_templates_extend_the_parser(tmp_path):
    path = tmp_path / "extra.yaml"
    path.write_text("skills:\n  - skill: open X\n    tasks: [open_drawer]\n    patterns:\n"
                    "      - (open|pull) {X}\n")
    parser = TemplateParser.from_files(path)
    assert parser.parse("open the top drawer").target == "top drawer"
    assert parser.parse("open the top drawer").skill == "open X"
    assert parser.parse("put the tomato in the plate").skill == "put X in the plate"  # built-ins kept
    only = TemplateParser.from_files(path, include_builtin=False)
    with pytest.raises(InstructionError):
        only.parse("put the tomato in the plate")
    inline = TemplateParser().with_templates({"skills": [{"skill": "push X", "patterns": ["push {X}"]}]})
    assert inline.parse("push the button").target == "button"


def test_bad_template_files(tmp_path):
    with pytest.raises(ConfigError, match="template file not found"):
        load_templates(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("skills:\n  - skill: open drawer\n    patterns: [open drawer]\n")
    with pytest.raises(ValueError, match="placeholder"):
        load_templates(bad)


def test_rewriting_parser_uses_rewriter_only_when_needed():
    calls = []

    def rewrite(text: str) -> str:
        calls.append(text)
        return "put the tomato in the plate"

    parser = RewritingParser(rewrite)
    assert parser.parse("close the red jar").skill == "close X"
    assert calls == []
    parsed = parser.parse("could the tomato end up on the dish")
    assert (parsed.target, parsed.skill) == ("tomato", "put X in the plate")
    assert parsed.instruction == "could the tomato end up on the dish"
    assert isinstance(parser, InstructionParser)


PLATE, TARGET = "put X in the plate", "put X on the target"
PARAPHRASES = [
    ("pick up the red block and put it on the target", "red block", TARGET),
    ("pick up the red block and then put it on the target", "red block", TARGET),
    ("Pick up the red block and place it on top of the target.", "red block", TARGET),
    ("grab the blue block and put it onto the target", "blue block", TARGET),
    ("take the green block and set it on the target", "green block", TARGET),
    ("pick the yellow block up and stack it on the target", "yellow block", TARGET),
    ("could you move the red block to the target", "red block", TARGET),
    ("bring the red block over to the target please", "red block", TARGET),
    ("put red block on target", "red block", TARGET),
    ("Please place a purple block onto the target, thanks", "purple block", TARGET),
    ("lift the orange block and drop it on the target", "orange block", TARGET),
    ("get the ketchup and carry it to the target", "ketchup", TARGET),
    ("grab the ketchup and place it on the plate", "ketchup", PLATE),
    ("pick up the milk and put it in the plate", "milk", PLATE),
    ("pick up the cream cheese and put it into the plate please", "cream cheese", PLATE),
    ("take the butter and drop it on the plate", "butter", PLATE),
    ("could you put ketchup in plate", "ketchup", PLATE),
    ("can you please move the milk to the plate", "milk", PLATE),
    ("bring the orange juice to the plate", "orange juice", PLATE),
    ("transfer the popcorn onto the plate", "popcorn", PLATE),
    ("I want you to put the cookies on the plate", "cookies", PLATE),
    ("put bbq sauce into plate please", "bbq sauce", PLATE),
    ("move ketchup onto plate", "ketchup", PLATE),
    ("drop the lemon block onto target", "lemon block", TARGET),
    ("robot, set the tomato sauce on the plate", "tomato sauce", PLATE),
    ("get the alphabet soup and bring it to the plate", "alphabet soup", PLATE),
    ("Would you place the chocolate pudding into a plate?", "chocolate pudding", PLATE),
    ("go ahead and put the salad dressing in the plate", "salad dressing", PLATE),
    ("pick up the red block and leave it in the plate", "red block", PLATE),
    ("grab the egg and put it on the top shelf", "egg", "put X on the top shelf"),
    ("put the egg on the upper shelf", "egg", "put X on the top shelf"),
    ("take the apple and place it in the bottom shelf", "apple", "put X on the bottom shelf"),
    ("move the apple onto the lower shelf", "apple", "put X on the bottom shelf"),
    ("place the egg in the shelf at the bottom", "egg", "put X on the bottom shelf"),
    ("grab the red wine and put it in the wine rack", "red wine", "put X in the wine rack"),
    ("rack the green bottle in the rack", "green bottle", "put X in the wine rack"),
    ("store the wine bottle in the wine rack", "wine bottle", "put X in the wine rack"),
    ("pick up the blue wine and stack it on the rack", "blue wine", "put X in the wine rack"),
    ("grab the red kettle and water the plant with it", "red kettle", "water the plant with X"),
    ("pick up the watering can and water the plants", "watering can", "water the plant with X"),
    ("pour the teapot over the plant", "teapot", "water the plant with X"),
    ("use the green kettle to water the plants", "green kettle", "water the plant with X"),
    ("cover the red jar with the lid", "red jar", "close X"),
    ("seal the blue jar", "blue jar", "close X"),
    ("put the lid back on the green jar", "green jar", "close X"),
    ("shut the yellow jar please", "yellow jar", "close X"),
    ("grab the ring and slide it over the red peg", "red peg", "put the ring on X"),
    ("take the hoop and drop it onto the blue peg", "blue peg", "put the ring on X"),
    ("insert the ring around the green peg", "green peg", "put the ring on X"),
    ("get the egg out of the frying pan", "egg", "take X off the frypan"),
    ("grab the sausage from the pan", "sausage", "take X off the frypan"),
    ("pick up the tomato off the frypan", "tomato", "take X off the frypan"),
    ("empty the pan of the mushroom", "mushroom", "take X off the frypan"),
    ("remove the egg off of the frying pan", "egg", "take X off the frypan"),
]


def test_paraphrase_set_is_large_enough():
    assert len(PARAPHRASES) >= 50


@pytest.mark.parametrize(("instruction", "target", "skill"), PARAPHRASES)
def test_paraphrases(instruction, target, skill):
    assert decompose_instruction(instruction) == (target, skill)


@pytest.mark.parametrize(("instruction", "steps"), [
    ("put the tomato in the plate and then close the jar", ["put tomato in the plate", "close jar"]),
    ("put the tomato in the plate then take the egg off the pan", ["put tomato in the plate",
                                                                   "take egg off the frypan"]),
    ("close the red jar and put the ketchup on the target", ["close red jar", "put ketchup on the target"]),
])
def test_multi_step_requests_are_refused_with_their_steps(instruction, steps):
    with pytest.raises(InstructionError, match=f"asks for {len(steps)} steps") as err:
        decompose_instruction(instruction)
    for step in steps:
        assert repr(step) in str(err.value)


def test_and_inside_an_object_name_is_not_a_second_step():
    assert decompose_instruction("put the salt and pepper in the plate") == ("salt and pepper", PLATE)


def test_multi_step_requests_are_not_silently_shortened_by_the_policy_or_a_rewriter():
    from abm.language.instruction import MultiStepInstructionError, RewritingParser
    from abm.language.roles import split_instruction

    text = "put the ketchup in the plate and then close the jar"
    with pytest.raises(MultiStepInstructionError):
        split_instruction(text, {1: "ketchup", 2: "jar"})
    with pytest.raises(MultiStepInstructionError):
        RewritingParser(lambda s: "put the ketchup in the plate").parse(text)
