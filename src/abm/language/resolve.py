"""Instructions in plain words: ``resolve_instruction(text, objects)`` -> the scene object, skill, task and confidence.

The templates (:mod:`abm.language.instruction`) understand a fixed set of phrasings and return the object
description X as written ("yellow cube", "yellow one"), which the scene may not hold. :func:`resolve_instruction`
maps an instruction onto one object of the scene (``objects``: the scene's object names) and one known skill,
in three stages, each tried only when the one before gives no answer above the confidence threshold:

1. **templates** (the fast path): :class:`~abm.language.instruction.TemplateParser` on the text as given;
   its X (and Y) are then matched against the scene's objects (below), so "put the yellow cube on the target"
   gives the object ``"yellow block"``;
2. **synonyms**: the same parser on the text with hand-written synonyms replaced by the templates' words
   ("pad", "mat", "square", "goal" -> "target"; "dish" -> "plate"; "cube", "brick" -> "block"; "cup" -> "mug";
   "pole", "post" -> "peg"; "hoop" -> "ring"; "skillet", "pan" -> "frypan"; "flowers" -> "plant"; ...);
3. **words**: no sentence shape at all. The text is cut into noun phrases ("mentions") at verbs, prepositions
   and determiners; each mention is matched against the scene's objects; a mention naming a skill's place (the
   target pad, the plate, the frypan, the shelf, the wine rack, the plant, the ring, the jar lid) or one of the
   scene's containers picks the skill, with verbs as weaker cues ("water", "pour", "close", "shut"). Without
   any such cue the scene decides: a scene that holds only the target pad is a pick-and-place onto it, so
   "grab the yellow one" is "put the yellow block on the target". The remaining mention is matched against
   the objects the skill can act on (its tasks' catalog categories: blocks and groceries for the target,
   mugs for watering, jars for closing, ...).

**Matching a description to an object** (:func:`match_object`): each word of the description is compared
with the object's name, its aliases (a hand-written table: "cheese" is the cream cheese, "coffee pot" the
moka pot, "soup can" the alphabet soup, ...), the generic nouns of its catalog category ("box", "carton" for
groceries, "container" for jars) and its colour (the one its name says, or a weaker implied one: ketchup is
red, milk white). Colours are compared as colours ("violet" is purple, "turquoise" cyan), a colour the object
does not have rules it out, a word naming another object of the scene counts against it, and a misspelt word
is corrected to the nearest scene word (:func:`difflib.get_close_matches`, ratio >= 0.75: "grn" -> "green").
Words that say nothing ("one", "thing", "little") are ignored, so "the yellow one" is whatever single object
is yellow.

**Confidence** in ``[0, 1]`` is the product of the skill's and the objects' confidences: 1 for a template
parse; otherwise the strength of the skill's cue (1 for a named place, 0.8 for a verb, 0.8 for a scene that
allows one skill only, shared between tied skills); an object's is its match score (the share of the
description it explains) times its margin over the next candidate (full once the runner-up scores at most
half as much). Below ``min_confidence`` (default :data:`RESOLVE_MIN_CONFIDENCE`) the instruction is refused
with the template parser's helpful :class:`~abm.language.instruction.InstructionError` (an
:class:`UnresolvedInstructionError` naming the best guess). Several steps or several objects
(:class:`~abm.language.instruction.MultiStepInstructionError`) are always refused, never merged.

**One positive command.** Before any stage, an instruction that is not one positive command about one object is
refused whole (:class:`~abm.language.instruction.NotOneCommandError`, one line quoting the words): a negation,
condition, alternative or exclusion (:mod:`abm.language.one_command`; the scene's object names never count), and
swapped roles, a place of the scene named as the thing to carry ("put the target on the yellow block"), which the
template and word stages check on the description of X. No later stage reads such a text. A reading of confidence
0 is never an answer, whatever ``min_confidence``; a refusal quotes the words it read as X and why they fit no
object (or several equally).

A :class:`Resolution` gives the ``canonical`` instruction, the skill with the scene's object names
("put the yellow block on the target"), which the template parser reads back as exactly that object and
skill: pass it to a policy (``abm run`` and ``abm ground`` do). ``docs/grounding.md`` records how often it is
right on 73 hand-written instructions (``benchmarks/instruction_resolution.py``).
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any

from abm.errors import ConfigError
from abm.language.instruction import (
    CARRIED_PLACES,
    PLACEHOLDER,
    SECOND_PLACEHOLDER,
    InstructionError,
    MultiStepInstructionError,
    NotOneCommandError,
    ParsedInstruction,
    TemplateParser,
    check_one_command,
    default_parser,
    load_templates,
)
from abm.language.one_command import swapped
from abm.language.roles import destination_for
from abm.sim.catalog import CATALOG
from abm.sim.tasks import TASKS

RESOLVE_MIN_CONFIDENCE = 0.5
"""Smallest confidence :func:`resolve_instruction` answers with; below it the instruction is refused."""

# --- the skills: their places, tasks and the catalog categories each task acts on ----------------------------

TARGET_SKILL = "put X on the target"
PLATE_SKILL = "put X in the plate"
CONTAINER_SKILL = "put X in Y"
TOP_SHELF_SKILL = "put X on the top shelf"
BOTTOM_SHELF_SKILL = "put X on the bottom shelf"
RACK_SKILL = "put X in the wine rack"
WATER_SKILL = "water the plant with X"
CLOSE_SKILL = "close X"
RING_SKILL = "put the ring on X"
PAN_SKILL = "take X off the frypan"

SKILL_PLACES: dict[str, tuple[str, ...]] = {t.skill: t.places for t in load_templates().skills}
"""Each built-in skill's place objects (catalog names; ``places`` in ``templates.yaml`` or a task's ``skills``): what
a mention of the place means, never its X."""

PLACES: frozenset[str] = frozenset(p for places in SKILL_PLACES.values() for p in places)

def task_categories(task: str) -> tuple[str, ...]:
    """The catalog categories a benchmark task's X belongs to (its ``Task.categories``; none for a task the
    benchmark does not have, e.g. one a user template file names)."""
    return tuple(TASKS[task].categories) if task in TASKS else ()

CONTAINER_CATEGORY = "container"
"""The catalog category of put_in_container's Y."""

# --- words ----------------------------------------------------------------------------------------------------

COLOURS: dict[str, str] = {
    **{c: c for c in ("red", "green", "blue", "yellow", "orange", "purple", "pink", "cyan", "white", "brown",
                      "black", "grey", "silver")},
    "gray": "grey", "violet": "purple", "lilac": "purple", "magenta": "pink", "turquoise": "cyan", "teal": "cyan",
    "aqua": "cyan", "crimson": "red", "scarlet": "red", "lime": "green", "navy": "blue",
    "metal": "silver", "metallic": "silver", "steel": "silver", "wooden": "brown", "wood": "brown",
}
"""Colour words -> the colour they name."""

PHRASES: dict[str, str] = {
    "on top of": "onto", "frying pan": "frypan", "fry pan": "frypan", "landing pad": "target",
    "bottle rack": "rack", "wine rack": "rack", "wine holder": "rack", "bottle holder": "rack", "pot plant": "plant",
    "potted plant": "plant", "flower pot": "plant", "bottle of wine": "wine bottle", "can of soup": "soup can",
    "tin of soup": "soup can", "box of cookies": "cookies box", "carton of milk": "milk carton",
    "jar lid": "lid", "little bit": "", "a bit": "",
    **{f"target {w}": "target" for w in ("area", "zone", "spot", "square", "pad", "marker", "mat")},
}
"""Word groups read as one word (or dropped) before anything else."""

WORDS: dict[str, str] = {
    **dict.fromkeys(("cube", "cubes", "brick", "bricks", "blocks"), "block"),
    **dict.fromkeys(("cup", "cups", "mugs", "teacup"), "mug"),
    **dict.fromkeys(("pole", "poles", "post", "posts", "stick", "sticks", "pin", "rod", "rods", "spike", "pegs",
                     "dowel"), "peg"),
    **dict.fromkeys(("hoop", "donut", "doughnut", "washer", "loop", "rings"), "ring"),
    **dict.fromkeys(("pad", "mat", "marker", "goal", "square", "mark", "cross", "bullseye", "targets"), "target"),
    **dict.fromkeys(("dish", "saucer", "plates"), "plate"),
    **dict.fromkeys(("skillet", "pan", "wok", "saucepan", "pans"), "frypan"),
    **dict.fromkeys(("flowers", "flower", "plants", "houseplant", "flowerpot"), "plant"),
    **dict.fromkeys(("shelves", "shelving", "bookshelf", "cupboard", "shelve"), "shelf"),
    **dict.fromkeys(("cap", "caps", "lids"), "lid"),
    **dict.fromkeys(("holder", "racks"), "rack"),
    **dict.fromkeys(("cookie", "biscuit", "biscuits"), "cookies"),
    "bowls": "bowl", "trays": "tray", "baskets": "basket", "bottles": "bottle", "jars": "jar", "catsup": "ketchup",
}
"""Single words -> the word the templates and the catalog use."""

ALIASES: dict[str, tuple[str, ...]] = {
    "bbq sauce": ("barbecue sauce", "barbecue", "bbq"),
    "cookies": ("cookies box", "cookies packet"),
    "cream cheese": ("cheese", "philadelphia"),
    "ketchup": ("tomato ketchup",),
    "milk": ("milk carton",),
    "orange juice": ("juice", "oj"),
    "chocolate pudding": ("pudding", "chocolate"),
    "alphabet soup": ("soup", "soup can"),
    "salad dressing": ("dressing",),
    "tomato sauce": ("pasta sauce", "marinara"),
    "popcorn": ("pop corn",),
    "wine bottle": ("wine",),
    "moka pot": ("moka", "coffee pot", "coffee maker", "espresso maker", "espresso pot", "percolator"),
    "porcelain mug": ("china mug", "porcelain", "china"),
    "white bowl": ("bowl",),
    "wooden tray": ("tray",),
    "wine rack": ("rack",),
    "jar lid": ("lid",),
}
"""Other names of catalog objects (in the canonical words of :data:`WORDS`)."""

IMPLIED_COLOURS: dict[str, tuple[str, ...]] = {
    "ketchup": ("red",), "tomato sauce": ("red",), "milk": ("white",), "orange juice": ("orange",),
    "chocolate pudding": ("brown",), "bbq sauce": ("brown",), "moka pot": ("silver",), "porcelain mug": ("white",),
    "wooden tray": ("brown",), "basket": ("brown",), "plate": ("white",), "target": ("white", "red"),
    "wine rack": ("brown",), "shelf": ("brown",), "frypan": ("black",), "jar lid": ("grey",), "ring": ("grey",),
}
"""Colours a catalog object shows without its name saying so (weaker evidence than a named colour)."""

GENERIC_NOUNS: dict[str, tuple[str, ...]] = {
    "grocery": ("box", "carton", "can", "tin", "package", "packet", "food", "product", "groceries", "bottle"),
    "block": ("toy",),
    "mug": ("vessel", "pot"),
    "bottle": ("bottle",),
    "jar": ("container", "pot"),
    "container": ("container", "receptacle", "bin"),
}
"""Nouns that fit any object of a catalog category."""

VAGUE: frozenset[str] = frozenset(
    "one ones thing things object objects item items stuff piece guy little small smaller big bigger large tiny "
    "other same kind sort".split())
"""Words that say nothing about which object: ignored when matching."""

TOP_WORDS: frozenset[str] = frozenset({"top", "upper", "high", "higher", "highest", "uppermost", "topmost"})
BOTTOM_WORDS: frozenset[str] = frozenset({"bottom", "lower", "low", "lowest", "lowermost", "bottommost"})

_FUNCTION_WORDS: frozenset[str] = frozenset((
    "a an the this that these those my your his her their our its some any "
    "in into inside on onto to toward towards over off of from out with using by beside next at under upon within "
    "near across through for around up down back away there here where which what "
    "and then but so or after afterwards finally also too "
    "it them i you me we us he she they robot please kindly thanks thank just now ok okay hey "
    "can could would will should must may might shall let lets be is are was goes go going belongs belong needs "
    "need want wanted like mind make sure try do does done have has get gets got "
    "put putting place placing set setting drop dropping move moving lay leave position store stack pop plonk "
    "shove slot pick grab grasp take lift hold bring carry transfer deliver fetch give use "
    "close shut seal screw twist fit cover remove clear empty slide insert thread hang "
    "water watering pour tip tilt fill sprinkle irrigate gently carefully neatly slowly quickly softly"
).split())
"""Words that end a mention (determiners, prepositions, verbs, polite words, pronouns)."""

VERB_CUES: dict[str, dict[str, float]] = {
    WATER_SKILL: dict.fromkeys(("water", "watering", "pour", "sprinkle", "irrigate"), 0.8),
    CLOSE_SKILL: dict.fromkeys(("close", "shut", "seal", "screw"), 0.8),
    RING_SKILL: {"thread": 0.5},
    PAN_SKILL: dict.fromkeys(("remove", "clear", "empty"), 0.3),
}
"""Verbs that suggest a skill, with the cue's strength in ``[0, 1]`` (a named place is 1)."""

PLACE_ONLY_CUES: dict[str, float] = {WATER_SKILL: 0.45}
"""Skills whose place alone is a weak cue without one of their verbs ("put the red mug on the plant")."""

MOVE_VERBS: frozenset[str] = frozenset(
    "grab grasp pick take get lift hold move put place set drop bring carry fetch stack transfer deliver lay "
    "position store pop plonk shove slot".split())
"""Verbs that let the scene alone pick the skill ("grab the yellow one" where only a target pad is)."""

REMOVAL_WORDS: frozenset[str] = frozenset({"off", "from", "out", "remove", "unload"})
"""Words that take an object away from a place: only the frypan skill does that."""

REFUSED_WORDS: frozenset[str] = frozenset(
    "open unscrew uncap unseal loosen untwist unstack undo knock shake spin rotate flip turn stir break hide push "
    "pull throw eat drink look point touch show find wipe clean wash kick squeeze crush smash "
    "under underneath beneath below next beside behind near left right front between".split())
"""Words of actions and places no skill has (opening, pushing; beside, under): the word stage never guesses."""

_LEAD_INS: frozenset[str] = frozenset("a an the this that these those my your up".split())
"""Words between a move verb and the object it moves ("pick up the ...")."""

_PREPOSITIONS: frozenset[str] = frozenset("in into inside on onto to toward towards over".split())
_SUBJECT_VERBS: frozenset[str] = frozenset("goes go belongs belong needs need should must".split())
"""Words after a sentence's first mention that make it the thing to move ("the pink one goes on the target")."""

SCENE_ONLY_CONFIDENCE = 0.8
"""Skill confidence when the text names no place and the scene allows one skill only."""

TYPO_RATIO = 0.75
"""Smallest :class:`difflib.SequenceMatcher` ratio for reading an unknown word as a scene word ("grn" -> "green")."""


def _words(text: str) -> list[str]:
    """Lower-case words of ``text``: punctuation dropped, ``_``/``-`` as spaces, ``'s`` kept in the word."""
    s = text.lower().replace("\u2019", "'").replace("_", " ").replace("-", " ")
    s = re.sub(r"[^\w\s']", " ", s)
    return [w.strip("'") for w in s.split() if w.strip("'")]


def canonical_words(text: str) -> list[str]:
    """``text`` as the canonical words matching uses: :data:`PHRASES` joined, :data:`WORDS` and colour
    synonyms replaced (``"Grab the violet cube!"`` -> ``["grab", "the", "purple", "block"]``)."""
    words = _words(text)
    phrases = sorted(((p.split(), r.split()) for p, r in PHRASES.items()), key=lambda pr: -len(pr[0]))
    out: list[str] = []
    i = 0
    while i < len(words):
        for phrase, replacement in phrases:
            if words[i:i + len(phrase)] == phrase:
                out += replacement
                i += len(phrase)
                break
        else:
            out.append(words[i])
            i += 1
    return [COLOURS.get(w, WORDS.get(w, w)) for w in out]


# --- objects --------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ObjectWords:
    """What words can describe one scene object.

    Attributes:
        name: the object's name in the scene.
        category: its catalog category (``None`` for a name the catalog does not know).
        colours: colours its name says (``"yellow block"`` -> ``{"yellow"}``).
        implied: colours it shows without its name saying so (:data:`IMPLIED_COLOURS`).
        nouns: the other words of its name and aliases.
        aliases: its name and other names, as canonical word tuples (:data:`ALIASES`).
        generic: nouns of its category (:data:`GENERIC_NOUNS`).
    """

    name: str
    category: str | None
    colours: frozenset[str]
    implied: frozenset[str]
    nouns: frozenset[str]
    aliases: tuple[tuple[str, ...], ...]
    generic: frozenset[str]

    @property
    def vocabulary(self) -> frozenset[str]:
        """Every word that describes this object."""
        return self.colours | self.implied | self.nouns | self.generic


@cache
def object_words(name: str) -> ObjectWords:
    """The :class:`ObjectWords` of an object name (catalog names get their aliases, category and colours)."""
    key = " ".join(_words(name))
    entry = CATALOG.get(key)
    category = entry.category if entry is not None else None
    own = canonical_words(key)
    colours = frozenset(w for w in own if w in COLOURS)
    aliases = tuple(dict.fromkeys([tuple(own), *(tuple(canonical_words(a)) for a in ALIASES.get(key, ()))]))
    nouns = frozenset(w for a in aliases for w in a if w not in COLOURS)
    return ObjectWords(key, category, colours, frozenset(IMPLIED_COLOURS.get(key, ())), nouns, aliases,
                       frozenset(GENERIC_NOUNS.get(category or "", ())))


_ALIAS_WORDS: frozenset[str] = frozenset(w for a in ALIASES.values() for p in a for w in canonical_words(p))


def _find(seq: Sequence[str], sub: Sequence[str]) -> int:
    """Start of the first occurrence of ``sub`` in ``seq``, or -1."""
    n = len(sub)
    return next((i for i in range(len(seq) - n + 1) if list(seq[i:i + n]) == list(sub)), -1) if n else -1


def match_object(words: Sequence[str], obj: ObjectWords, scene_words: frozenset[str] = frozenset()) -> float:
    """How well a description (canonical words, :func:`canonical_words`) fits an object, in ``[0, 1]``: the share of
    its informative words the object explains (module docstring).

    Args:
        words: the description's canonical words (vague words such as "one" are ignored).
        obj: the object's words (:func:`object_words`).
        scene_words: the words describing any object of the scene: one of them that does not describe ``obj``
            counts against it.

    Returns:
        0 when a colour rules the object out; 0.5 for a description with no informative word.
    """
    tokens = [w for w in words if w not in VAGUE and w not in TOP_WORDS | BOTTOM_WORDS]
    if not tokens:
        return 0.5
    covered = [False] * len(tokens)
    for alias in sorted(obj.aliases, key=len, reverse=True):
        start = _find(tokens, alias)
        while start >= 0 and any(covered[start:start + len(alias)]):
            nxt = _find(tokens[start + 1:], alias)
            start = -1 if nxt < 0 else start + 1 + nxt
        if start >= 0:
            covered[start:start + len(alias)] = [True] * len(alias)
    head = tokens[-1]  # the noun that says what kind of thing is meant ("the purple teapot")
    if not covered[-1] and head not in COLOURS and head not in obj.nouns and head not in obj.generic:
        return 0.0  # a teapot is not a block, whatever its colour: never trade the kind for a colour match
    gain = weight = 0.0
    against = False
    for word, done in zip(tokens, covered, strict=True):
        if done:
            gain, weight = gain + 1.0, weight + 1.0
            continue
        if word in COLOURS:
            colour = COLOURS[word]
            weight += 1.0
            if colour in obj.colours:
                gain += 1.0
            elif colour in obj.implied:
                gain += 0.6
            elif obj.colours:
                return 0.0  # "the red one" is not the blue block
            elif obj.implied:
                against = True
            else:
                gain += 0.2  # nothing known about its colour
            continue
        weight += 1.0
        if word in obj.nouns:
            gain += 1.0
        elif word in obj.generic:
            gain += 0.7
        elif word in scene_words:
            against = True  # the word describes another object of the scene
        else:
            weight -= 0.5  # an unknown word: counts half
    score = gain / weight if weight > 0 else 0.5
    return score * (0.3 if against else 1.0)


def _confidence(scores: Sequence[float]) -> float:
    """Confidence in the best of ``scores``: the best score times its margin over the runner-up (full once the
    runner-up scores at most half as much)."""
    if not scores:
        return 0.0
    ranked = sorted(scores, reverse=True)
    best, second = ranked[0], (ranked[1] if len(ranked) > 1 else 0.0)
    if best <= 0:
        return 0.0
    return best * min(1.0, 2.0 * (1.0 - second / best))


@dataclass(frozen=True)
class ObjectChoice:
    """The object a description means among candidates.

    Attributes:
        name: the chosen object's name.
        confidence: its confidence in ``[0, 1]`` (:func:`_confidence` of the candidates' scores).
        phrase: the description, as canonical words joined by spaces.
        scores: candidate name -> :func:`match_object` score.
    """

    name: str
    confidence: float
    phrase: str
    scores: dict[str, float] = field(default_factory=dict)


class _Scene:
    """The scene's objects with their words, and the vocabulary used for typos and contradictions."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(dict.fromkeys(" ".join(_words(n)) for n in names if _words(n)))
        self.original = {" ".join(_words(n)): n for n in names if _words(n)}
        self.words = {n: object_words(n) for n in self.names}
        self.vocabulary = frozenset(w for o in self.words.values() for w in o.vocabulary)
        self.known = any(n in PLACES or self.words[n].category == CONTAINER_CATEGORY for n in self.names)
        typo_words = self.vocabulary | set(COLOURS) | set(WORDS.values()) | {"top", "bottom", "shelf"}
        self._typo_words = sorted(w for w in typo_words if len(w) >= 3)
        self._known = self.vocabulary | _FUNCTION_WORDS | VAGUE | set(COLOURS) | set(WORDS.values()) | TOP_WORDS | \
            BOTTOM_WORDS | _ALIAS_WORDS

    def fix_typos(self, words: Sequence[str]) -> list[str]:
        """``words`` with each unknown word of 3+ letters replaced by the nearest scene word (ratio >= 0.75)."""
        out = []
        for w in words:
            if w in self._known or len(w) < 3 or not w.isalpha():
                out.append(w)
                continue
            close = difflib.get_close_matches(w, self._typo_words, n=1, cutoff=TYPO_RATIO)
            out.append(close[0] if close else w)
        return out

    def choose(self, words: Sequence[str], candidates: Sequence[str]) -> ObjectChoice | None:
        """The candidate ``words`` describe best, with its confidence (``None`` without candidates)."""
        if not candidates:
            return None
        scores = {c: match_object(words, self.words[c], self.vocabulary) for c in candidates}
        best = max(candidates, key=lambda c: scores[c])
        return ObjectChoice(best, _confidence(list(scores.values())), " ".join(words), scores)

    def x_candidates(self, skill: str, tasks: Sequence[str], second: str | None = None) -> list[str]:
        """The scene's objects the skill can act on as X: its tasks' categories, or any object the catalog does not
        know that is no place (a real scene's own names); never ``second``."""
        wanted = {c for t in tasks for c in task_categories(t)}
        out = []
        for n in self.names:
            category = self.words[n].category
            if n == second or n in PLACES:
                continue
            if category is None or not wanted or category in wanted:
                if skill in SKILL_PLACES and category == CONTAINER_CATEGORY:
                    continue  # a container is never what a known skill moves
                out.append(n)
        return out

    def containers(self) -> list[str]:
        """The scene's objects that can be Y of ``put X in Y`` (containers other than a skill's place)."""
        return [n for n in self.names if self.words[n].category == CONTAINER_CATEGORY and n not in PLACES]

    def supports(self, skill: str) -> bool:
        """Whether the scene holds what the skill needs besides X (always, for a scene without known places)."""
        if not self.known:
            return True
        if skill == CONTAINER_SKILL:
            return bool(self.containers())
        places = SKILL_PLACES.get(skill)
        if places is None:
            return True  # a user's skill: nothing known about it
        category = {CLOSE_SKILL: "jar", RING_SKILL: "peg"}.get(skill)
        return any(p in self.names for p in places) or (
            category is not None and any(self.words[n].category == category for n in self.names))


# --- the result -----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Resolution:
    """An instruction resolved onto the scene (:func:`resolve_instruction`).

    Attributes:
        instruction: the text as given.
        target: the object X, one of the scene's names (the parser's X as written when the scene names none).
        skill: the skill text with ``X`` (and ``Y``), e.g. ``"put X on the target"``.
        task: the benchmark task of the skill and X (``"pick_block"`` for a block on the target, ``""`` for a
            user's skill without tasks).
        confidence: in ``[0, 1]`` (module docstring).
        second: Y of a two-target skill (a scene container), else ``None``.
        tasks: every task of the skill.
        method: ``"templates"``, ``"synonyms"`` or ``"words"``: the stage that answered.
        phrase: the words that described X.
    """

    instruction: str
    target: str
    skill: str
    task: str
    confidence: float
    second: str | None = None
    tasks: tuple[str, ...] = ()
    method: str = "templates"
    phrase: str = ""

    @property
    def targets(self) -> tuple[str, ...]:
        """``(X,)``, or ``(X, Y)`` for a two-target skill."""
        return (self.target,) if self.second is None else (self.target, self.second)

    @property
    def destination(self) -> str | None:
        """Where the skill brings X: the object its task declares (``Task.destination``: the target pad, the plate,
        the wine rack, the shelf, the plant; X itself for close X and the ring's peg; :attr:`second` for a
        two-target skill, the one concept of a place object beside X), ``None`` when it has none (take X off the
        frypan) (:func:`abm.language.roles.destination_for`)."""
        return destination_for((self.task,) if self.task else self.tasks, self.targets)

    @property
    def canonical(self) -> str:
        """The instruction in the templates' words with the scene's names: ``"put the yellow block on the
        target"`` (the template parser reads it back as :attr:`target`, :attr:`second` and :attr:`skill`)."""
        names = {PLACEHOLDER: self.target, SECOND_PLACEHOLDER: self.second}
        return " ".join(f"the {names[w]}" if w in names and names[w] else w for w in self.skill.split())

    def as_record(self) -> dict[str, Any]:
        """JSON-ready form (logs, ``summary.json``)."""
        return {"instruction": self.instruction, "target": self.target, "second": self.second, "skill": self.skill,
                "task": self.task, "confidence": round(float(self.confidence), 4), "method": self.method,
                "phrase": self.phrase, "canonical": self.canonical, "destination": self.destination}


class UnresolvedInstructionError(InstructionError):
    """An instruction :func:`resolve_instruction` refuses: no skill and scene object above the threshold.

    Attributes:
        guess: the best answer found (below the threshold), or ``None``.
    """

    def __init__(self, message: str, guess: Resolution | None = None) -> None:
        super().__init__(message)
        self.guess = guess


# --- resolving ------------------------------------------------------------------------------------------------

def _task_for(tasks: Sequence[str], target: str) -> str:
    """The task among ``tasks`` whose categories include the target's (the first task otherwise)."""
    category = object_words(target).category
    return next((t for t in tasks if category in task_categories(t)), tasks[0] if tasks else "")


def _from_parse(text: str, parsed: ParsedInstruction, scene: _Scene, method: str, skill_confidence: float
                ) -> Resolution | None:
    """A parse's X (and Y) matched to the scene's objects."""
    tasks = tuple(parsed.tasks)
    if not scene.names:
        return Resolution(text, parsed.target, parsed.skill, tasks[0] if tasks else "", skill_confidence,
                          parsed.second, tasks, method, parsed.target)
    if scene.known and not scene.supports(parsed.skill):
        skill_confidence *= 0.4  # the scene lacks the skill's place (a plate asked for, a target pad there)
    second: ObjectChoice | None = None
    if parsed.second is not None:
        second = scene.choose(scene.fix_typos(canonical_words(parsed.second)), scene.containers() or scene.names)
        if second is None:
            return None
    words = scene.fix_typos(canonical_words(parsed.target))
    choice = scene.choose(words, scene.x_candidates(parsed.skill, tasks, second.name if second else None))
    if choice is None:
        return None
    _refuse_swapped(text, words, scene, parsed.second or "")
    confidence = skill_confidence * choice.confidence * (second.confidence if second else 1.0)
    return Resolution(text, choice.name, parsed.skill, _task_for(tasks, choice.name), confidence,
                      second.name if second else None, tasks, method, choice.phrase)


def _refuse_swapped(text: str, words: Sequence[str], scene: _Scene, goal: str = "") -> None:
    """Raise when ``words``, the thing to carry, name a place (a skill's place other than a part it carries, or a
    scene container) better than any other object of the scene: the roles are swapped ("put the plate in the
    ketchup"; ``goal``: what the text names as the destination, for the message)."""
    place = _place_of(words, scene)
    if place is None or place in CARRIED_PLACES:
        return
    score = match_object(words, object_words(place), scene.vocabulary)
    movable = [n for n in scene.names if n not in PLACES and scene.words[n].category != CONTAINER_CATEGORY]
    if score > max((match_object(words, scene.words[n], scene.vocabulary) for n in movable), default=0.0):
        raise NotOneCommandError(text, swapped(" ".join(words), goal))


def _direct_object(words: Sequence[str]) -> list[str]:
    """The mention a move verb acts on ("put the target on ..." -> ``["target"]``), or the mention the text starts
    with when a preposition or "goes" follows it ("the target goes on ..."); ``[]`` when there is none."""
    start = 0
    while start < len(words) and words[start] in _FUNCTION_WORDS and words[start] not in MOVE_VERBS:
        start += 1  # polite words, "could you"
    i = start
    if i < len(words) and words[i] in MOVE_VERBS:
        i += 1
        while i < len(words) and words[i] in _LEAD_INS:
            i += 1
    elif i < len(words) and words[i] not in _FUNCTION_WORDS:
        end = i
        while end < len(words) and words[end] not in _FUNCTION_WORDS:
            end += 1
        if end == len(words) or words[end] in _LEAD_INS or words[end] not in _SUBJECT_VERBS | _PREPOSITIONS:
            return []
    mention = []
    while i < len(words) and words[i] not in _FUNCTION_WORDS:
        mention.append(words[i])
        i += 1
    return mention


def _rewrite(text: str) -> str:
    """``text`` with :data:`PHRASES` / :data:`WORDS` synonyms replaced by the templates' words."""
    return " ".join(canonical_words(text))


def _mentions(words: Sequence[str]) -> list[list[str]]:
    """The noun phrases of ``words``: runs of words between function words (verbs, prepositions, determiners)."""
    out: list[list[str]] = [[]]
    for w in words:
        if w in _FUNCTION_WORDS:
            if out[-1]:
                out.append([])
        else:
            out[-1].append(w)
    return [m for m in out if m]


def _place_of(mention: Sequence[str], scene: _Scene) -> str | None:
    """The skill place or scene container a mention names, else ``None``."""
    options = [p for p in PLACES if p not in scene.names] + list(scene.names)
    scores = {}
    for name in options:
        s = match_object(mention, object_words(name), scene.vocabulary)
        scores[name] = s * (1.0 if name in scene.names or not scene.known else 0.9)
    best = max(scores, key=lambda n: scores[n])
    if scores[best] < 0.6:
        return None
    if best in PLACES or object_words(best).category == CONTAINER_CATEGORY:
        return best
    return None


def _skill_cues(words: Sequence[str], mentions: Sequence[Sequence[str]], scene: _Scene, skills: Sequence[str]
                ) -> tuple[dict[str, float], set[int], str | None]:
    """``(skill -> cue strength, indices of the place mentions, the container Y named)``."""
    cues = dict.fromkeys(skills, 0.0)
    used: set[int] = set()
    second: str | None = None
    level = ("top" if TOP_WORDS.intersection(words) else "") + ("bottom" if BOTTOM_WORDS.intersection(words) else "")
    verbs = {skill: max((v.get(w, 0.0) for w in words), default=0.0) for skill, v in VERB_CUES.items()}
    for i, mention in enumerate(mentions):
        place = _place_of(mention, scene)
        if place is None:
            continue
        used.add(i)
        if place == "shelf":
            for skill, lvl in ((TOP_SHELF_SKILL, "top"), (BOTTOM_SHELF_SKILL, "bottom")):
                if skill in cues:
                    cues[skill] = max(cues[skill], 1.0 if level == lvl else 0.5 if not level else 0.0)
            continue
        if place in PLACES:
            for skill, places in SKILL_PLACES.items():
                if place in places and skill in cues and skill not in (TOP_SHELF_SKILL, BOTTOM_SHELF_SKILL):
                    weak = PLACE_ONLY_CUES.get(skill)
                    cues[skill] = 1.0 if weak is None or verbs.get(skill, 0.0) > 0 else weak
        elif CONTAINER_SKILL in cues and place in scene.containers():
            cues[CONTAINER_SKILL] = 1.0
            second = second or place
    for skill, strength in verbs.items():
        if skill in cues:
            cues[skill] = max(cues[skill], strength)
    if REMOVAL_WORDS.intersection(words):  # "take the block off the target" is no skill but the frypan's
        cues = {s: (c if s == PAN_SKILL else 0.0) for s, c in cues.items()}
    return cues, used, second


def _from_words(text: str, scene: _Scene, parser: TemplateParser) -> Resolution | None:
    """Stage 3: the skill from the places, containers and verbs named, X from the other mentions."""
    words = scene.fix_typos(canonical_words(text))
    if REFUSED_WORDS.intersection(words):
        return None
    carried = _direct_object(words)
    if carried:
        _refuse_swapped(text, carried, scene)
    templates = {t.skill: t for t in parser.templates.skills}
    skills = [s for s in SKILL_PLACES if s in templates]
    mentions = _mentions(words)
    cues, used, second = _skill_cues(words, mentions, scene, skills)
    rest = [m for i, m in enumerate(mentions) if i not in used]
    if not rest:
        return None
    viable = [s for s in skills if scene.supports(s)]
    strongest = max(cues.values(), default=0.0)
    ranked: list[tuple[float, str]] = []
    if strongest > 0:
        best = max((cues[s] for s in viable), default=0.0)
        if best <= 0:
            return None  # the text asks for a place the scene does not hold
        tied = [s for s in viable if cues[s] == best]
        ranked = [(best * best / strongest / len(tied), s) for s in tied]
    else:  # no place named: the scene decides, for a plain "grab X" only
        if len(rest) != 1 or not MOVE_VERBS.intersection(words) or REMOVAL_WORDS.intersection(words):
            return None
        ranked = [(SCENE_ONLY_CONFIDENCE / max(1, len(viable)), s) for s in viable]
    answers: list[Resolution] = []
    for skill_confidence, skill in ranked:
        tasks = tuple(templates[skill].tasks)
        y: ObjectChoice | None = None
        if skill == CONTAINER_SKILL:
            if second is None:
                continue
            y = ObjectChoice(second, 1.0, second)
        candidates = scene.x_candidates(skill, tasks, y.name if y else None)
        choices = [c for m in rest if (c := scene.choose(m, candidates)) is not None]
        if not choices:
            continue
        choice = max(choices, key=lambda c: c.confidence)
        confidence = skill_confidence * choice.confidence
        answers.append(Resolution(text, choice.name, skill, _task_for(tasks, choice.name), confidence,
                                  y.name if y else None, tasks, "words", choice.phrase))
    return max(answers, key=lambda r: r.confidence, default=None)


def _scene_names(objects: Iterable[str] | Mapping[int, str] | None) -> list[str]:
    """The object names of ``objects`` (names, or a segmentation id -> name mapping)."""
    if objects is None:
        return []
    values = objects.values() if isinstance(objects, Mapping) else objects
    return [str(v) for v in values]


def resolve_instruction(text: str, objects: Iterable[str] | Mapping[int, str] | None,
                        min_confidence: float = RESOLVE_MIN_CONFIDENCE, parser: TemplateParser | None = None
                        ) -> Resolution:
    """Resolve an instruction in plain words onto one object of the scene and one known skill (module docstring).

    Args:
        text: the instruction ("could you please move that little yellow thing onto the square?").
        objects: the scene's object names (or segmentation id -> name, as ``Episode.object_names``); empty or
            ``None``: the templates alone decide and X stays as written.
        min_confidence: the smallest confidence answered, in ``[0, 1]``.
        parser: the template parser (default: the built-in templates).

    Returns:
        The :class:`Resolution`: ``target`` (one of ``objects``), ``skill``, ``task``, ``confidence``; its
        ``canonical`` text is the instruction a policy should be given.

    Raises:
        MultiStepInstructionError: several steps or several objects (never merged into one).
        UnresolvedInstructionError: no answer reaches ``min_confidence`` (an :class:`InstructionError`, so a
            ``ValueError``, with the template parser's list of known skills and phrasings).
    """
    if not 0.0 <= min_confidence <= 1.0:
        raise ConfigError(f"min_confidence must be in [0, 1], got {min_confidence}")
    parser = parser or default_parser()
    names = _scene_names(objects)
    check_one_command(text, names)  # before any stage reads objects out of a negation, condition or choice
    scene = _Scene(names)
    guesses: list[Resolution] = []
    rewritten = _rewrite(text)
    readings = [(text, "templates", 1.0)]  # the templates as written, then after the synonyms
    if rewritten != " ".join(_words(text)):
        readings.append((rewritten, "synonyms", 0.95))
    for reading, method, skill_confidence in readings:
        try:
            parsed = parser.parse(reading, names=names)
        except MultiStepInstructionError:
            raise
        except InstructionError:
            continue
        answer = _from_parse(text, parsed, scene, method, skill_confidence)
        if answer is not None:
            guesses.append(answer)
            if answer.confidence >= min_confidence and answer.confidence > 0:
                return _named(answer, scene)
    if scene.names:
        answer = _from_words(text, scene, parser)
        if answer is not None:
            guesses.append(answer)
            if answer.confidence >= min_confidence and answer.confidence > 0:
                return _named(answer, scene)
    guess = max(guesses, key=lambda r: r.confidence, default=None)
    raise _refusal(text, parser, scene, guess, min_confidence)


def _named(answer: Resolution, scene: _Scene) -> Resolution:
    """``answer`` with the scene's own spelling of its object names."""
    def own(name: str | None) -> str | None:
        return None if name is None else scene.original.get(name, name)

    return Resolution(answer.instruction, own(answer.target) or answer.target, answer.skill, answer.task,
                      answer.confidence, own(answer.second), answer.tasks, answer.method, answer.phrase)


def _refusal(text: str, parser: TemplateParser, scene: _Scene, guess: Resolution | None, min_confidence: float
             ) -> UnresolvedInstructionError:
    """The refusal: the template parser's message (known skills, phrasings) with what was understood."""
    held = f"the scene holds: {', '.join(scene.names)}" if scene.names else "the scene names no objects"
    if guess is not None and round(guess.confidence, 2) > 0:
        reason = (f"the best reading, {guess.canonical!r} ({guess.phrase!r} read as {guess.target!r}), has "
                  f"confidence {guess.confidence:.2f} < {min_confidence:.2f}; {held}; name the object and where it "
                  "goes")
    elif guess is not None:
        reason = f"{_no_fit(guess, scene)} ({held})"
    else:
        reason = f"no scene object and skill fit its words ({held})"
    normalized = parser.normalize(text) if text.strip() else ""
    message = str(parser._refusal(text, normalized, reason))
    return UnresolvedInstructionError(message, guess)


def _no_fit(guess: Resolution, scene: _Scene) -> str:
    """Why a reading has no confidence: the words read as X fit no object its skill moves, or fit several equally."""
    candidates = scene.x_candidates(guess.skill, guess.tasks, guess.second)
    words = guess.phrase.split()
    scores = {n: match_object(words, scene.words[n], scene.vocabulary) for n in candidates}
    best = max(scores.values(), default=0.0)
    skill = guess.skill.replace(SECOND_PLACEHOLDER, f"the {guess.second}") if guess.second else guess.skill
    if best <= 0:
        movable = ", ".join(candidates) or "nothing"
        return (f"it reads {guess.phrase!r} as the object to move, and that fits no object {skill!r} can move "
                f"({movable}); name one of them")
    tied = [n for n, v in scores.items() if v == best]
    return f"{guess.phrase!r} fits {' and '.join(tied)} equally; name one of them"
