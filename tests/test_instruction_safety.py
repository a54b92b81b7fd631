"""An instruction is acted on only if it is one positive command about one object (abm.language.one_command):
negations, conditions, alternatives, exclusions and swapped roles are refused in one line that quotes the words,
by the resolver, the template parser, every fallback after them, ``abm run`` (dry-run, replay, MuJoCo) and
``abm ground --strict``; plain commands, polite ones and object names that hold such words still resolve."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from tests.test_target_decision import OPEN, OPEN_YAML, recording  # noqa: F401 (the replay folder fixture)

from abm.cli import main as cli_main
from abm.errors import RefusedError
from abm.language.instruction import (
    MultiStepInstructionError,
    NotOneCommandError,
    RewritingParser,
    decompose_instruction,
    default_parser,
)
from abm.language.one_command import ALTERNATIVE, CONDITION, EXCLUSION, NEGATION, SWAPPED, find_trigger
from abm.language.resolve import UnresolvedInstructionError, resolve_instruction
from abm.language.roles import split_roles
from abm.robot import run_robot

SCENES = {
    "pick": ("target", "red block", "blue block", "yellow block", "green block"),
    "pick_unseen": ("target", "cyan block", "orange block", "pink block"),
    "plate": ("plate", "ketchup", "milk", "butter"),
    "bowl": ("white bowl", "basket", "cookies", "cream cheese", "red block"),
    "jar": ("jar lid", "red jar", "green jar", "blue jar"),
    "water": ("plant", "red mug", "white mug", "butter"),
    "peg": ("ring", "red peg", "blue peg", "yellow peg"),
    "pan": ("frypan", "butter", "cookies", "cream cheese"),
    "shelf": ("shelf", "cookies", "cream cheese", "bbq sauce"),
    "wine": ("wine rack", "wine bottle", "bbq sauce", "butter"),
}

# (instruction, scene, kind, the words quoted as the reason)
REFUSED = [
    # negations, early and late, contractions, capitals, politeness
    ("Do NOT put the yellow block on the target.", "pick", NEGATION, "do not"),
    ("don't put the red block on the target, put the blue one", "pick", NEGATION, "don't"),
    ("Never put the green block on the target", "pick", NEGATION, "never"),
    ("never ever place the blue cube on the pad", "pick", NEGATION, "never ever"),
    ("please avoid putting the red block on the target", "pick", NEGATION, "avoid"),
    ("Kindly refrain from moving the yellow block to the target", "pick", NEGATION, "refrain from"),
    ("put the yellow block on the target -- actually, don't", "pick", NEGATION, "don't"),
    ("put the yellow block on the target? no.", "pick", NEGATION, "no"),
    ("Dont grab the yellow one", "pick", NEGATION, "dont"),
    ("you shouldn't put the red cube on the mat", "pick", NEGATION, "shouldn't"),
    ("the blue block must not go on the target", "pick", NEGATION, "must not"),
    ("stop putting the green block on the target", "pick", NEGATION, "stop"),
    ("I don\u2019t want the yellow block on the target", "pick", NEGATION, "don't"),
    ("the ketchup should never go in the plate", "plate", NEGATION, "never"),
    ("do not close the red jar", "jar", NEGATION, "do not"),
    ("please don't water the plant with the red mug", "water", NEGATION, "don't"),
    ("could you please not put the ketchup on the plate", "plate", NEGATION, "not"),
    ("neither the red nor the blue block goes on the target", "pick", NEGATION, "neither"),
    ("put nothing on the target", "pick", NEGATION, "nothing"),
    ("Avoid the red block; put the blue block on the target", "pick", NEGATION, "avoid"),
    ("under no circumstances put the yellow block on the target", "pick", NEGATION, "no"),
    ("leave the milk, don't move it to the plate", "plate", NEGATION, "don't"),
    ("You can't take the butter off the frypan", "pan", NEGATION, "can't"),
    # conditions
    ("if the yellow block is there put the blue block on the target", "pick", CONDITION, "if"),
    ("put the red block on the target if the blue one is gone", "pick", CONDITION, "if"),
    ("Unless the yellow block is already there, put it on the target", "pick", CONDITION, "unless"),
    ("When the gripper is free, put the yellow block on the target", "pick", CONDITION, "when"),
    ("put the yellow block on the target when you see it", "pick", CONDITION, "when"),
    ("whenever possible place the blue cube on the pad", "pick", CONDITION, "whenever"),
    ("put the red block on the target only if it is free", "pick", CONDITION, "only if"),
    ("in case the target is empty put the red block there", "pick", CONDITION, "in case"),
    ("as long as it is free, put the red block on the target", "pick", CONDITION, "as long as"),
    ("once the blue block moves, put the red one on the target", "pick", CONDITION, "once"),
    ("put the ketchup in the plate provided it is empty", "plate", CONDITION, "provided"),
    ("close the red jar while the lid is near", "jar", CONDITION, "while"),
    ("assuming the plate is clean, put the milk on it", "plate", CONDITION, "assuming"),
    ("put the red block on the target if you can see it", "pick", CONDITION, "if"),
    # alternatives
    ("the yellow or the green block", "pick", ALTERNATIVE, "or"),
    ("put the yellow or green block on the target", "pick", ALTERNATIVE, "or"),
    ("put either the yellow block or the blue block on the target", "pick", ALTERNATIVE, "either"),
    ("Grab the red block OR the blue block and put it on the target", "pick", ALTERNATIVE, "or"),
    ("put whichever block you like on the target", "pick", ALTERNATIVE, "whichever"),
    ("put the ketchup or the milk in the plate", "plate", ALTERNATIVE, "or"),
    ("water the plant with the red mug or the white mug", "water", ALTERNATIVE, "or"),
    ("close the red jar, or the blue jar", "jar", ALTERNATIVE, "or"),
    ("put the butter in the white bowl or the basket", "bowl", ALTERNATIVE, "or"),
    ("put whatever is closest on the target", "pick", ALTERNATIVE, "whatever"),
    ("move the red/blue block to the target", "pick", ALTERNATIVE, "or"),
    # exclusions
    ("put anything but the red block on the target", "pick", EXCLUSION, "anything but"),
    ("put every block except the red one on the target", "pick", EXCLUSION, "except"),
    ("put a block other than the yellow one on the target", "pick", EXCLUSION, "other than"),
    ("put the block that is not the yellow one on the target", "pick", EXCLUSION, "not the"),
    ("Not the red block! Put the blue block on the target", "pick", EXCLUSION, "not the"),
    ("put the blue block on the target without touching the red block", "pick", EXCLUSION, "without"),
    ("put the blue block on the target, ignoring the red one", "pick", EXCLUSION, "ignoring"),
    ("apart from the ketchup, put something in the plate", "plate", EXCLUSION, "apart from"),
    ("put the milk instead of the butter on the plate", "plate", EXCLUSION, "instead of"),
    ("put the red block rather than the blue block on the target", "pick", EXCLUSION, "rather than"),
    ("besides the red jar, close a jar", "jar", EXCLUSION, "besides"),
    ("put a block on the target, but not the red one", "pick", EXCLUSION, "but not"),
    ("take anything but the butter off the frypan", "pan", EXCLUSION, "anything but"),
    ("put the ring on any peg except the red peg", "peg", EXCLUSION, "except"),
    ("put something else on the top shelf", "shelf", EXCLUSION, "else"),
    ("skip the yellow block and put the blue block on the target", "pick", EXCLUSION, "skip"),
    ("Leave the red cube alone, move the green one onto the pad", "pick", EXCLUSION, "alone"),
    ("the yellow block stays where it is; put the blue one on the target", "pick", EXCLUSION, "stays"),
    # swapped roles: the place named as the thing to carry
    ("put the target on the yellow block", "pick", SWAPPED, "target"),
    ("put the plate in the ketchup", "plate", SWAPPED, "plate"),
    ("Please place the pad on the red cube", "pick", SWAPPED, "target"),
    ("pick up the plate and put it on the milk", "plate", SWAPPED, "plate"),
    ("the target goes on the green block", "pick", SWAPPED, "target"),
    ("put the white bowl in the butter", "bowl", SWAPPED, "white bowl"),
    ("place the basket into the cookies", "bowl", SWAPPED, "basket"),
    ("put the frypan on the butter", "pan", SWAPPED, "frypan"),
    ("put the shelf on the cookies", "shelf", SWAPPED, "shelf"),
    ("move the wine rack to the wine bottle", "wine", SWAPPED, "wine rack"),
    ("put the plant on the red mug", "water", SWAPPED, "plant"),
]

# (instruction, scene, the object it must resolve to)
ACCEPTED = [
    ("put the ketchup in the plate", "plate", "ketchup"),
    ("Please put the ketchup on the plate.", "plate", "ketchup"),
    ("the butter goes on the plate", "plate", "butter"),
    ("plate the milk", "plate", "milk"),
    ("put the butter on the plate for me, thanks", "plate", "butter"),
    ("stack the blue block on the target", "pick", "blue block"),
    ("now put the green block on the target", "pick", "green block"),
    ("grab the yellow one", "pick", "yellow block"),
    ("pick up the red block and put it on the target", "pick", "red block"),
    ("Could you please put the BLUE block onto the target?", "pick", "blue block"),
    ("put the red block on the target if you can", "pick", "red block"),
    ("if you could, place the green cube on the pad", "pick", "green block"),
    ("put the yellow block on the target if you could, please", "pick", "yellow block"),
    ("put the orange block on the target", "pick_unseen", "orange block"),
    ("put the cookies in the white bowl", "bowl", "cookies"),
    ("put the cream cheese into the basket", "bowl", "cream cheese"),
    ("close the red jar", "jar", "red jar"),
    ("put the lid on the blue jar", "jar", "blue jar"),
    ("slide the ring onto the red peg", "peg", "red peg"),
    ("water the plant with the red mug", "water", "red mug"),
    ("take the butter off the frypan", "pan", "butter"),
    ("put the cookies on the top shelf", "shelf", "cookies"),
    ("put the wine bottle in the rack", "wine", "wine bottle"),
    # object names holding words that would otherwise be refused, matched as whole words
    ("put the notebook on the target", ("target", "notebook", "red block"), "notebook"),
    ("put the ordinary mug on the target", ("target", "ordinary mug", "red block"), "ordinary mug"),
    ("put the either box on the target", ("target", "either box", "blue block"), "either box"),
    ("put the whenever box on the target", ("target", "whenever box", "red block"), "whenever box"),
    ("put the no-name can on the target", ("target", "no-name can", "red block"), "no-name can"),
]


def _scene(scene: str | tuple[str, ...]) -> tuple[str, ...]:
    return SCENES[scene] if isinstance(scene, str) else scene


@pytest.mark.parametrize(("text", "scene", "kind", "words"), REFUSED, ids=[t for t, *_ in REFUSED])
def test_not_one_positive_command_is_refused_in_one_line_quoting_the_words(text, scene, kind, words) -> None:
    objects = _scene(scene)
    with pytest.raises(NotOneCommandError) as err:
        resolve_instruction(text, objects)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"refusing instruction {text!r}")
    assert err.value.trigger.kind == kind and err.value.trigger.words == words
    assert f"({kind}: {words!r} " in message  # the words that triggered it, quoted
    assert getattr(err.value, "guess", None) is None  # no reading, so no object the instruction excludes
    assert isinstance(err.value, RefusedError) and isinstance(err.value, MultiStepInstructionError)
    # a lower threshold does not let any stage answer either
    with pytest.raises(NotOneCommandError):
        resolve_instruction(text, objects, min_confidence=0.0)


def test_the_refusal_table_is_large_and_varied() -> None:
    assert len(REFUSED) >= 60 and len({t.lower() for t, *_ in REFUSED}) == len(REFUSED)
    kinds = {kind for _, _, kind, _ in REFUSED}
    assert kinds == {NEGATION, CONDITION, ALTERNATIVE, EXCLUSION, SWAPPED}
    assert len({scene for _, scene, _, _ in REFUSED}) >= 8


@pytest.mark.parametrize(("text", "scene", "kind", "words"),
                         [case for case in REFUSED if case[2] != SWAPPED], ids=[t for t, _, k, _ in REFUSED
                                                                                 if k != SWAPPED])
def test_no_fallback_reads_a_refused_instruction(text, scene, kind, words) -> None:
    """The templates alone, a rewriting parser and the scene-name fallback of split_roles all refuse it too."""
    objects = _scene(scene)
    with pytest.raises(NotOneCommandError):
        decompose_instruction(text)
    rewritten: list[str] = []
    rewriter = RewritingParser(lambda t: rewritten.append(t) or "put the red block on the target", default_parser())
    with pytest.raises(NotOneCommandError):
        rewriter.parse(text)
    assert rewritten == []  # never rewritten into a command it did not give
    with pytest.raises(NotOneCommandError):
        split_roles(text, dict(enumerate(objects)))
    assert find_trigger(text) is not None


def test_swapped_roles_are_refused_by_the_templates_without_a_scene() -> None:
    for text, place in (("put the plate in the ketchup", "plate"), ("move the wine rack to the wine bottle",
                                                                    "wine rack"),
                        ("put the target pad into the bowl", "target pad")):
        with pytest.raises(NotOneCommandError, match=f"swapped roles: {place!r} is where things go") as err:
            decompose_instruction(text)
        assert err.value.trigger.words == place
    assert decompose_instruction("put the ketchup in the plate") == ("ketchup", "put X in the plate")
    assert decompose_instruction("put the ring on the red peg") == ("red peg", "put the ring on X")


@pytest.mark.parametrize(("text", "scene", "target"), ACCEPTED, ids=[t for t, *_ in ACCEPTED])
def test_one_positive_command_still_resolves_to_its_object(text, scene, target) -> None:
    resolution = resolve_instruction(text, _scene(scene))
    assert resolution.target == target and resolution.confidence >= 0.5


def test_names_of_the_scene_are_not_triggers_but_the_same_words_elsewhere_are() -> None:
    assert find_trigger("put the either box on the target", ["either box"]) is None
    assert find_trigger("put the either box on the target") is not None
    trigger = find_trigger("put the either box or the red block on the target", ["either box"])
    assert trigger is not None and trigger.words == "or"
    with pytest.raises(NotOneCommandError, match="'or'"):
        resolve_instruction("put the either box or the red block on the target", ("target", "either box",
                                                                                  "red block"))
    # words are whole words: "orange", "butter", "notebook", "nothing"-free names pass
    for text in ("put the orange block on the target", "put the butter on the plate", "put the notebook away"):
        assert find_trigger(text) is None


def test_refusals_quote_what_was_read_and_never_a_zero_confidence() -> None:
    """A reading no object fits, or one that fits several equally, says so instead of "confidence 0.00"."""
    cases = (("serve the plate", ("plate", "tomato sauce", "alphabet soup"),
              "it reads 'serve' as the object to move, and that fits no object 'put X in the plate' can move "
              "(tomato sauce, alphabet soup)"),
             ("put the block on the target", SCENES["pick"],
              "'block' fits red block and blue block and yellow block and green block equally; name one of them"),
             ("grab the red block", ("plate", "tomato sauce"), "it reads 'red block' as the object to move"))
    for text, scene, reason in cases:
        for threshold in (0.5, 0.0):  # a reading of confidence 0 is never accepted, whatever the threshold
            with pytest.raises(UnresolvedInstructionError) as err:
                resolve_instruction(text, scene, min_confidence=threshold)
            assert reason in str(err.value) and "confidence 0.00" not in str(err.value)
    with pytest.raises(UnresolvedInstructionError, match=r"\('sauce' read as 'tomato sauce'\), has confidence 0.40"):
        resolve_instruction("put the sauce on the plate", ("shelf", "tomato sauce", "alphabet soup"))


# ---- the command line: abm run (dry-run, replay, MuJoCo) and abm ground --strict ------------------------------

def test_abm_run_refuses_in_one_line_and_moves_nothing(recording, shared_tiny_run, tmp_path,  # noqa: F811
                                                      cli_errors) -> None:
    folder, _ = recording
    sim = tmp_path / "sim.yaml"
    sim.write_text("arm: {kind: sim, task: pick_block, split: seen, seed: 0, resolution: 48}\n" + OPEN_YAML)
    replay = tmp_path / "replay.yaml"
    replay.write_text(f"cameras: {{kind: replay, path: {folder}}}\narm: {{kind: dry-run}}\n" + OPEN_YAML)
    for robot, extra, instruction, quoted in (
            (sim, ["--dry-run"], "do not put the yellow block on the target", "negation: 'do not'"),
            (replay, [], "if the yellow block is there put the blue block on the target", "condition: 'if'"),
            (sim, [], "put the target on the yellow block", "swapped roles: 'target'")):
        log_dir = tmp_path / f"log{len(list(tmp_path.iterdir()))}"
        assert cli_main(["run", "--robot", str(robot), "--run", str(shared_tiny_run), "--steps", "1", "--log",
                         str(log_dir), "--instruction", instruction, *extra]) == 2
        (error,) = cli_errors()
        assert error.startswith(f"abm: error: refused before moving: refusing instruction {instruction!r}")
        assert quoted in error
        (line,) = [json.loads(x) for x in (log_dir / "steps.jsonl").read_text().splitlines()]
        assert line["status"] == "refused" and quoted in line["reason"]
        assert not list(log_dir.glob("step_*.npz"))  # no keyframe was predicted, nothing moved


def test_a_camera_that_names_no_objects_gets_the_same_refusal(tmp_path) -> None:
    """Without the scene's names (a real camera) the templates refuse it: run_robot logs it, the policy never runs."""
    camera, arm = SimpleNamespace(object_names=None), SimpleNamespace(commands=[])
    for text, kind in (("put the yellow or the green block on the target", ALTERNATIVE),
                       ("put the plate in the ketchup", SWAPPED)):
        with pytest.raises(NotOneCommandError) as err:
            run_robot(None, camera, arm, text, OPEN, 1, tmp_path / kind)  # type: ignore[arg-type]
        assert err.value.trigger.kind == kind
        (line,) = [json.loads(x) for x in (tmp_path / kind / "steps.jsonl").read_text().splitlines()]
        assert line == {"step": 0, "status": "refused", "reason": str(err.value)}


def test_abm_ground_refuses_in_one_line_strict_or_not(tmp_path, cli_errors) -> None:
    for strict in (["--strict"], []):
        out = tmp_path / f"g{len(strict)}"
        assert cli_main(["ground", "--out", str(out), "--instruction", "never put the blue block in the plate",
                         "--resolution", "32", *strict]) == 2
        (error,) = cli_errors()
        assert error == ("abm: error: refusing instruction 'never put the blue block in the plate': it is not one "
                         "positive command (negation: 'never' negates the command: abm acts on what to do, never on "
                         "what not to do); give one positive command about one object, e.g. 'put the blue block on "
                         "the target'")
        assert not (out / "summary.json").exists()
