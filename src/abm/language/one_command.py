"""Is an instruction one positive command? The words that make abm refuse it before anything reads its objects.

abm acts on an instruction only when it is one positive command about one object. Text that also says what *not*
to do, or when, or offers a choice, reads as the opposite command once its objects are picked out ("do not put the
yellow block on the target" names the yellow block and the target), so it is refused whole, and never read by a
later, looser stage (:mod:`abm.language.resolve`). :func:`find_trigger` looks for, as whole words:

* **negations**: "not", "never", "don't" (any "...n't"), "no", "avoid", "refrain from", "stop";
* **conditions**: "if", "unless", "when", "whenever", "while", "until", "once", "in case", "as long as", ...;
* **alternatives**: "or", "either", "whichever", "whatever", "alternatively";
* **exclusions**: "except", "but", "anything but", "other than", "apart from", "besides", "without", "instead of",
  "rather than", "ignore", "skip", "forget", "alone", "stays", "else", and "not" before a determiner ("not the red
  block").

Words that belong to a name of the scene's objects are skipped ("put the either box on the target" with an object
called "either box"). Swapped roles (the place named as the thing to carry: "put the target on the yellow block")
need the templates and the scene; :class:`abm.language.instruction.TemplateParser` and
:func:`abm.language.resolve.resolve_instruction` check them and refuse them with :func:`refusal_message` too.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass

NEGATION = "negation"
CONDITION = "condition"
ALTERNATIVE = "alternative"
EXCLUSION = "exclusion"
SWAPPED = "swapped roles"

_DETERMINERS = ("the", "a", "an", "that", "this", "those", "these", "any", "my", "your")

TRIGGERS: dict[str, tuple[str, ...]] = {
    # exclusions first: "not the X" and "anything but" are exclusions, not a bare "not" / "but"
    EXCLUSION: (
        *(f"not {d}" for d in _DETERMINERS), "anything but", "everything but", "all but", "any but", "but not",
        "except", "excepting", "except for", "excluding", "exclude", "besides", "apart from", "aside from",
        "other than", "but", "instead", "instead of", "rather than", "without", "ignore", "ignoring", "else",
        "save for", "leave out", "skip", "skipping", "forget", "forgetting", "omit", "omitting", "alone",
        "untouched", "hands off", "stay", "stays", "remain", "remains",
    ),
    NEGATION: (
        *(f"{v} not" for v in ("do", "does", "did", "must", "should", "shall", "will", "would", "can", "need")),
        "not", "never", "never ever", "no", "nothing", "none", "neither", "nor", "avoid", "avoiding",
        "refrain", "refrain from", "stop", "cease", "cannot", "dont", "doesnt", "didnt", "wont", "cant", "shouldnt",
        "wouldnt", "couldnt", "mustnt", "isnt", "arent", "wasnt", "werent", "havent", "hasnt", "neednt", "shant",
    ),
    CONDITION: (
        "if", "only if", "unless", "when", "whenever", "while", "whilst", "until", "till", "once", "provided",
        "providing", "assuming", "suppose", "supposing", "in case", "as long as", "as soon as", "otherwise",
        "depending",
    ),
    ALTERNATIVE: ("or", "either", "whichever", "whatever", "alternatively"),
}
"""Phrases (lower case, whole words) that make an instruction more than one positive command, by kind."""

REASONS: dict[str, str] = {
    NEGATION: "negates the command: abm acts on what to do, never on what not to do",
    CONDITION: "makes the command conditional: abm cannot check a condition before it acts",
    ALTERNATIVE: "offers a choice between objects: abm moves the one object the instruction names",
    EXCLUSION: "excludes an object instead of naming the one to move",
}
"""Why each kind is refused (after the quoted words)."""

POLITE_CONDITIONS: tuple[str, ...] = (
    "if you can", "if you could", "if you would", "if you please", "if possible", "if you don't mind",
    "if you do not mind", "if you dont mind", "when you can",
)
"""Polite wrappers that only look like conditions: not triggers at the start or the end of an instruction (the
templates' ``polite_suffixes`` include "if you can"); "put the block on the target if you can see it" is refused."""

_POLITE_TAIL = frozenset({"please", "thanks", "thank", "you", "for", "me", "now"})


@dataclass(frozen=True)
class Trigger:
    """Why an instruction is not one positive command.

    Attributes:
        kind: :data:`NEGATION`, :data:`CONDITION`, :data:`ALTERNATIVE`, :data:`EXCLUSION` or :data:`SWAPPED`.
        words: the words of the instruction that triggered it, as written in lower case (``"don't"``,
            ``"anything but"``; for swapped roles the place named as the thing to carry).
        reason: what is wrong, after the quoted words.
    """

    kind: str
    words: str
    reason: str


def command_words(text: str) -> list[str]:
    """Lower-case words of ``text``: curly apostrophes straightened, ``_``/``-`` as spaces, ``/`` as "or", other
    punctuation dropped, apostrophes kept inside words (``"Don't!"`` -> ``["don't"]``)."""
    s = str(text).lower().replace("\u2019", "'").replace("\u2018", "'")
    s = re.sub(r"[_\-]", " ", s.replace("/", " or "))  # "red/blue block": a choice
    s = re.sub(r"[^\w\s']", " ", s)
    return [w.strip("'") for w in s.split() if w.strip("'")]


def _phrases() -> list[tuple[tuple[str, ...], str]]:
    """Every trigger phrase as words, with its kind, longest first (ties in :data:`TRIGGERS` order)."""
    out = [(tuple(p.split()), kind) for kind, phrases in TRIGGERS.items() for p in phrases]
    return sorted(out, key=lambda pk: -len(pk[0]))


_PHRASES = _phrases()
_TRIGGER_WORDS = frozenset(w for words, _ in _PHRASES for w in words)


def _protected(words: list[str], names: Iterable[str]) -> list[bool]:
    """Which of ``words`` belong to an object name of the scene that holds a trigger word, or to a polite wrapper
    (:data:`POLITE_CONDITIONS`) at the start or the end."""
    keep = [False] * len(words)
    for phrase in map(command_words, POLITE_CONDITIONS):
        n = len(phrase)
        if words[:n] == phrase:
            keep[:n] = [True] * n
        for end in range(len(words), n - 1, -1):
            if words[end - n:end] == phrase:
                keep[end - n:end] = [True] * n
                break
            if words[end - 1] not in _POLITE_TAIL:
                break
    for name in names:
        own = command_words(name)
        if not own or not _TRIGGER_WORDS.intersection(own):
            continue
        for i in range(len(words) - len(own) + 1):
            if words[i:i + len(own)] == own:
                keep[i:i + len(own)] = [True] * len(own)
    return keep


def find_trigger(text: str, names: Iterable[str] = ()) -> Trigger | None:
    """The first negation, condition, alternative or exclusion of ``text`` (module docstring), else ``None``.

    Args:
        text: the instruction as given.
        names: the scene's object names: their words are never triggers.
    """
    words = command_words(text)
    keep = _protected(words, names)
    for i, word in enumerate(words):
        if keep[i]:
            continue
        if word.endswith("n't"):  # don't, doesn't, won't, can't, shouldn't, ...
            return Trigger(NEGATION, word, REASONS[NEGATION])
        for phrase, kind in _PHRASES:
            end = i + len(phrase)
            if tuple(words[i:end]) == phrase and not any(keep[i:end]):
                return Trigger(kind, " ".join(phrase), REASONS[kind])
    return None


def swapped(place: str, carried: str = "") -> Trigger:
    """The :class:`Trigger` of an instruction that names a place (``place``: its words as written) as the thing to
    carry; ``carried`` names what it would then move (the object named as the destination)."""
    what = f", and {carried!r} as where it goes" if carried else ""
    return Trigger(SWAPPED, place, f"is where things go, named as the thing to carry{what}: say which object to "
                                   "move and put the place after it")


def refusal_message(instruction: str, trigger: Trigger) -> str:
    """The one-line refusal: the instruction, the quoted words and why, and what abm accepts."""
    return (f"refusing instruction {instruction!r}: it is not one positive command ({trigger.kind}: "
            f"{trigger.words!r} {trigger.reason}); give one positive command about one object, e.g. 'put the blue "
            "block on the target'")
