"""Instruction decomposition: instruction -> (target object description X, skill text with "X").

ABM splits every instruction into the object to ground (X, e.g. ``"tomato"``) and the robot skill
the policy conditions on (e.g. ``"put X in the plate"``). The split is done by templates kept as data
(``templates.yaml`` in this package); users extend them with :func:`load_templates` or
:meth:`TemplateParser.with_templates`. Any other parser (e.g. one backed by a language model that
rewrites free-form text into a known template) plugs in through the :class:`InstructionParser`
protocol; :class:`RewritingParser` shows the shape of such a parser without shipping a network client.

Parsing is deterministic and explainable, in three steps, all driven by ``templates.yaml``:

1. *normalise*: lower case, punctuation removed, whitespace collapsed, polite prefixes/suffixes
   ("could you please", "... for me") stripped, determiners (a/an/the/this/that/...) and filler adverbs
   ("gently") dropped;
2. *fold* a two-clause form "<grasp verb> X [up] and [then] <clause with 'it'>" into that clause with X
   for "it" ("pick up the red block and put it on the target" -> "put red block on target");
3. *match* the skill patterns, whose verbs, prepositions and place names are synonym groups.

What is not one positive command (a negation, condition, alternative or exclusion: :mod:`abm.language.one_command`;
or a skill's place as X, "put the plate in the ketchup") is refused first, in one line, by
:class:`NotOneCommandError`. What cannot be one skill on one named object is refused with an
:class:`InstructionError` naming the reason and listing accepted phrasings: several steps or objects
(:class:`MultiStepInstructionError`), a pronoun instead of an object, a grasp without a goal, or text no pattern
matches. Compositional
instructions reuse trained skills because colour words and nouns such as "block" all stay inside X:
"put the red block in the plate" -> ("red block", "put X in the plate").
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple, NoReturn, Protocol, runtime_checkable

from abm.errors import ConfigError, RefusedError
from abm.files import load_yaml, parse_yaml
from abm.language.one_command import Trigger, find_trigger, refusal_message, swapped

PLACEHOLDER = "X"
SECOND_PLACEHOLDER = "Y"  # the second object of a two-target skill ("put X in Y": X is grasped, then placed in Y)
ARTICLES: frozenset[str] = frozenset({"a", "an", "the"})
_VOWELS = "aeiou"


class InstructionError(ConfigError):
    """An instruction the parser refuses (the message says why and lists the known skills with phrasings)."""


class MultiStepInstructionError(InstructionError):
    """An instruction that asks for several skills in a row, or for one skill on several objects ("all
    blocks", "the red block and the blue block"); abm runs one skill on one object per instruction."""


class NotOneCommandError(MultiStepInstructionError, RefusedError):
    """An instruction that is not one positive command about one object: a negation ("do not put ..."), a
    condition ("if ..."), an alternative ("the yellow or the green block"), an exclusion ("anything but ...") or
    swapped roles (the place named as the thing to carry: "put the target on the yellow block"). Its message is one
    line quoting the words that triggered it (:mod:`abm.language.one_command`). A :class:`MultiStepInstructionError`
    so every reader that never rewrites or re-reads such a refusal (the resolver's later stages, a
    :class:`RewritingParser`, :func:`abm.language.roles.split_roles`' scene-name fallback) passes it on.

    Attributes:
        trigger: the :class:`~abm.language.one_command.Trigger`: kind, the words, the reason.
    """

    def __init__(self, instruction: str, trigger: Trigger) -> None:
        super().__init__(refusal_message(instruction, trigger))
        self.trigger = trigger


def check_one_command(instruction: str, names: Collection[str] = ()) -> None:
    """Refuse ``instruction`` unless it is one positive command (no negation, condition, alternative or exclusion;
    :func:`abm.language.one_command.find_trigger`, whose words in ``names``, the scene's objects, do not count).

    Raises:
        NotOneCommandError: one line quoting the words that triggered it.
    """
    trigger = find_trigger(instruction, names)
    if trigger is not None:
        raise NotOneCommandError(instruction, trigger)


CARRIED_PLACES: frozenset[str] = frozenset({"ring", "hoop", "lid", "cap", "jar lid"})
"""Places a skill carries onto its X (the ring onto a peg, the lid onto a jar): named as the thing to move, they
are no swapped roles."""


@dataclass(frozen=True)
class ParsedInstruction:
    """The result of decomposing one instruction.

    Attributes:
        instruction: the original text.
        target: the object description X (lower case, no articles), e.g. ``"red block"``.
        skill: the skill text with the placeholder, e.g. ``"put X in the plate"``; a two-target skill has a
            second placeholder ``Y`` (``"put X in Y"``).
        tasks: benchmark tasks that use this skill (informative only).
        second: the second object description Y of a two-target skill (``None`` otherwise).
    """

    instruction: str
    target: str
    skill: str
    tasks: tuple[str, ...] = ()
    second: str | None = None

    @property
    def targets(self) -> tuple[str, ...]:
        """The objects of the instruction's sub-goals, in order: ``(X,)``, or ``(X, Y)`` for a two-target
        skill (grasp X, then place it in / on Y)."""
        return (self.target,) if self.second is None else (self.target, self.second)

    @property
    def prompt(self) -> str:
        """The CLIP text prompt for X: ``"a photo of a X"`` / ``"a photo of an X"``."""
        return clip_prompt(self.target)


def require_instruction(instruction: str | None, source: str = "the instruction") -> str:
    """``instruction`` unchanged, refusing ``None`` and empty or whitespace-only text.

    Args:
        source: where the text came from, for the message (``"--instruction"``, ``"the recording's instruction"``).

    Raises:
        InstructionError: (a ``ValueError``) naming ``source`` and the fix.
    """
    if instruction is None or not str(instruction).strip():
        raise InstructionError(f"{source} is empty; give the instruction to carry out, naming one object of the "
                               "scene, e.g. 'put the red block on the target'")
    return str(instruction)


def clip_prompt(target: str) -> str:
    """``"a photo of a {target}"``, with ``"an"`` when the description starts with a vowel letter."""
    target = " ".join(target.split())
    if not target:
        raise ValueError("cannot build a CLIP prompt for an empty object description")
    article = "an" if target[0].lower() in _VOWELS else "a"
    return f"a photo of {article} {target}"


@runtime_checkable
class InstructionParser(Protocol):
    """Anything that turns an instruction into a :class:`ParsedInstruction`.

    Implementations raise :class:`InstructionError` when they cannot decompose the text.
    """

    def parse(self, instruction: str) -> ParsedInstruction: ...


Synonyms = Mapping[str, tuple[str, ...]]
GRASP_GROUP = "grasp"
"""The synonym group whose verbs start a two-clause form ("pick up X and put it ...")."""

_TOKEN = re.compile(r"\{[xy]\}|\([^)]*\)|\[[^\]]*\]|<[^>]*>|[^\s()\[\]{}<>]+")


class SlotMatch(NamedTuple):
    """A pattern match: the object X, the number of required literal tokens, and Y (two-target skills)."""

    target: str
    specificity: int
    second: str | None = None


@dataclass(frozen=True)
class SkillTemplate:
    """One skill and the patterns that recognise it (see ``templates.yaml`` for the syntax).

    Attributes:
        skill: the skill text with the placeholder word ``X``.
        patterns: pattern texts; ``<name>`` refers to a group of ``synonyms``.
        tasks: benchmark tasks that use this skill: the ones a template file lists, and for the built-in
            templates every registered task whose own instructions parse to the skill (:func:`load_templates`).
        examples: instructions shown in refusal messages as accepted phrasings of this skill.
        synonyms: the synonym groups the patterns may use.
        places: the catalog objects the skill's text names as its place (the plate, the target pad): what a
            mention of the place means, never its X (:mod:`abm.language.resolve`).
    """

    skill: str
    patterns: tuple[str, ...]
    tasks: tuple[str, ...] = ()
    examples: tuple[str, ...] = ()
    synonyms: Synonyms = field(default_factory=dict, repr=False, compare=False)
    places: tuple[str, ...] = ()
    _compiled: tuple[tuple[re.Pattern[str], int], ...] = field(default=(), repr=False, compare=False)
    _lead_words: frozenset[str] = field(default=frozenset(), repr=False, compare=False)

    def __post_init__(self) -> None:
        if PLACEHOLDER not in self.skill.split():
            raise ConfigError(f"skill {self.skill!r} must contain the placeholder word {PLACEHOLDER!r}")
        if not self.patterns:
            raise ConfigError(f"skill {self.skill!r} has no patterns")
        compiled = tuple(_compile_pattern(p, self.synonyms) for p in self.patterns)
        two = SECOND_PLACEHOLDER in self.skill.split()
        if any(("Y" in regex.groupindex) != two for regex, _, _ in compiled):
            raise ConfigError(f"skill {self.skill!r}: every pattern must contain {{Y}} exactly when the skill text "
                              f"contains the second placeholder {SECOND_PLACEHOLDER!r}")
        object.__setattr__(self, "_compiled", tuple((regex, literals) for regex, literals, _ in compiled))
        object.__setattr__(self, "_lead_words", frozenset(w for _, _, lead in compiled for w in lead))

    @property
    def lead_words(self) -> frozenset[str]:
        """Words a pattern of this skill can start with (the verbs that begin a step)."""
        return self._lead_words

    def match(self, normalized: str, accept: Callable[[str], bool] | None = None) -> SlotMatch | None:
        """``(X, specificity, Y)`` of the most specific pattern matching ``normalized``, else ``None``
        (``Y`` is ``None`` for one-target skills).

        ``accept`` (optional) vetoes a captured X or Y; the next most specific pattern is then used.
        """
        best: SlotMatch | None = None
        for regex, literals in self._compiled:
            m = regex.fullmatch(" " + normalized)
            if m is None or (best is not None and literals <= best[1]):
                continue
            target = m.group("X").strip()
            second = m.group("Y").strip() if "Y" in regex.groupindex else None
            if accept is None or (accept(target) and (second is None or accept(second))):
                best = SlotMatch(target, literals, second)
        return best


def _expand_option(option: str, synonyms: Synonyms, pattern: str) -> list[str]:
    """One alternative of a pattern token -> its phrases (a ``<group>`` expands to the group)."""
    option = option.strip()
    if option.startswith("<") and option.endswith(">"):
        name = option[1:-1].strip()
        if name not in synonyms:
            known = ", ".join(f"<{g}>" for g in sorted(synonyms)) or "none"
            raise ConfigError(f"pattern {pattern!r} uses unknown synonym group <{name}> (known: {known})")
        return list(synonyms[name])
    return [option]


def _compile_pattern(
    pattern: str, synonyms: Synonyms = MappingProxyType({})
) -> tuple[re.Pattern[str], int, frozenset[str]]:
    """Pattern text -> (regex over ``" " + normalised text``, required literal tokens, leading words)."""
    tokens = _TOKEN.findall(pattern.lower())
    if tokens.count("{x}") != 1:
        raise ConfigError(f"pattern {pattern!r} must contain {{X}} exactly once")
    if tokens.count("{y}") > 1:
        raise ConfigError(f"pattern {pattern!r} may contain {{Y}} at most once")
    regex = ""
    literals = 0
    lead: set[str] = set()
    leading = True  # still collecting the words a match can start with
    for tok in tokens:
        if tok in ("{x}", "{y}"):
            regex += rf" (?P<{tok[1].upper()}>\S+(?: \S+)*?)"
            leading = False
            continue
        optional = tok.startswith("[")
        raw = tok[1:-1].split("|") if tok.startswith(("(", "[")) else [tok]
        phrases = [p for option in raw for p in _expand_option(option, synonyms, pattern)]
        options = sorted({o for o in (_drop_words(p, ARTICLES) for p in phrases) if o}, key=len, reverse=True)
        if not options:
            continue
        if leading:
            lead.update(o.split()[0] for o in options)
            leading = optional
        alternatives = "|".join(re.escape(o) for o in options)
        regex += f"(?: (?:{alternatives}))?" if optional else f" (?:{alternatives})"
        literals += 0 if optional else 1
    return re.compile(regex), literals, frozenset(lead)


def _drop_words(text: str, words: Collection[str]) -> str:
    """``text`` without the given words."""
    return " ".join(w for w in text.split() if w not in words)


def _clean_words(text: str, prefixes: Sequence[str] = (), suffixes: Sequence[str] = ()) -> list[str]:
    """Lower case, punctuation removed, polite prefixes/suffixes stripped (repeatedly); determiners kept."""
    if not isinstance(text, str):
        raise TypeError(f"instruction must be a string, got {type(text).__name__}")
    s = text.lower().replace("\u2019", "'").replace("_", " ")
    s = re.sub(r"[^\w\s'-]", " ", s)
    s = re.sub(r"(?<!\w)['-]|['-](?!\w)", " ", s)  # quotes / dashes not inside a word
    words = s.split()
    prefix_words = sorted((p.lower().split() for p in prefixes), key=len, reverse=True)
    suffix_words = sorted((p.lower().split() for p in suffixes), key=len, reverse=True)
    changed = True
    while changed and words:
        changed = False
        for p in prefix_words:
            if p and words[: len(p)] == p and len(words) > len(p):
                words = words[len(p) :]
                changed = True
                break
        for p in suffix_words:
            if p and words[-len(p) :] == p and len(words) > len(p):
                words = words[: -len(p)]
                changed = True
                break
    return words


def normalize_instruction(
    text: str,
    prefixes: Sequence[str] = (),
    suffixes: Sequence[str] = (),
    determiners: Collection[str] = ARTICLES,
) -> str:
    """Lower-case, strip punctuation, polite prefixes/suffixes and determiners; collapse spaces.

    ``"Please, put the Cream Cheese in a plate!"`` -> ``"put cream cheese in plate"``.
    """
    return " ".join(w for w in _clean_words(text, prefixes, suffixes) if w not in determiners)


def _union(*groups: Sequence[str]) -> tuple[str, ...]:
    """The entries of all groups, in order, without repeats."""
    return tuple(dict.fromkeys(w for g in groups for w in g))


def _merge_synonyms(base: Synonyms, extra: Synonyms) -> dict[str, tuple[str, ...]]:
    """``base`` with ``extra``'s groups added; a group in both gets the union of the phrases."""
    merged = {name: tuple(phrases) for name, phrases in base.items()}
    for name, phrases in extra.items():
        merged[name] = _union(merged.get(name, ()), phrases)
    return merged


@dataclass(frozen=True)
class TemplateSet:
    """Skill templates plus the vocabulary used around them (all read from ``templates.yaml``).

    Attributes:
        skills: the skills, in matching order (ties between equally specific patterns go to the first).
        polite_prefixes / polite_suffixes: phrases stripped from the start / end before matching.
        synonyms: phrase groups patterns refer to as ``<name>``; ``grasp`` drives the two-clause fold.
        determiners: words dropped everywhere (articles, "this", "that", ...).
        fillers: other words dropped everywhere (adverbs such as "gently", "carefully").
        pronouns: words standing for an already named object ("it"); replaced by the two-clause fold,
            refused as X.
        quantifiers: words asking for several or unspecified objects ("all", "every"); refused.
        clause_joins: joins of the two-clause fold ("and", "and then", "then").
        step_words: sequencing words ("then", "after that"); an unmatched instruction containing one
            is refused as a multi-step request.
    """

    skills: tuple[SkillTemplate, ...]
    polite_prefixes: tuple[str, ...] = ()
    polite_suffixes: tuple[str, ...] = ()
    synonyms: Synonyms = field(default_factory=dict, repr=False, compare=False)
    determiners: tuple[str, ...] = tuple(sorted(ARTICLES))
    fillers: tuple[str, ...] = ()
    pronouns: tuple[str, ...] = ()
    quantifiers: tuple[str, ...] = ()
    clause_joins: tuple[str, ...] = ()
    step_words: tuple[str, ...] = ()

    def merged(self, other: TemplateSet) -> TemplateSet:
        """A new set with ``other``'s skills tried first (patterns of the same skill text are merged).

        Word lists are united, synonym groups of the same name get both sets' phrases, and every
        skill is recompiled with the merged synonyms.
        """
        synonyms = _merge_synonyms(self.synonyms, other.synonyms)
        by_skill: dict[str, tuple[tuple[str, ...], ...]] = {}
        for t in (*other.skills, *self.skills):
            old = by_skill.get(t.skill, ((), (), (), ()))
            by_skill[t.skill] = (_union(old[0], t.patterns), _union(old[1], t.tasks), _union(old[2], t.examples),
                                 _union(old[3], t.places))
        skills = tuple(
            SkillTemplate(skill, patterns, tasks, examples, synonyms, places)
            for skill, (patterns, tasks, examples, places) in by_skill.items()
        )
        return TemplateSet(
            skills,
            _union(self.polite_prefixes, other.polite_prefixes),
            _union(self.polite_suffixes, other.polite_suffixes),
            synonyms,
            _union(self.determiners, other.determiners),
            _union(self.fillers, other.fillers),
            _union(self.pronouns, other.pronouns),
            _union(self.quantifiers, other.quantifiers),
            _union(self.clause_joins, other.clause_joins),
            _union(self.step_words, other.step_words),
        )


_WORD_LISTS = (
    "polite_prefixes",
    "polite_suffixes",
    "determiners",
    "fillers",
    "pronouns",
    "quantifiers",
    "clause_joins",
    "step_words",
)


def _string_list(data: Mapping[str, Any], key: str) -> tuple[str, ...]:
    """The word list ``data[key]`` (lower case, spaces collapsed); empty when absent."""
    value = data.get(key, [])
    if not isinstance(value, list) or any(isinstance(v, bool) or not isinstance(v, str | int | float) for v in value):
        raise ConfigError(
            f"templates {key!r} must be a list of words or phrases, got {value!r} (YAML reads bare "
            "on/off/yes/no as booleans: quote them)"
        )
    return tuple(" ".join(str(v).lower().split()) for v in value)


def parse_templates(data: dict[str, Any], base_synonyms: Synonyms | None = None) -> TemplateSet:
    """Build a :class:`TemplateSet` from the YAML structure (``skills`` and the optional word lists).

    ``base_synonyms`` are synonym groups the patterns may use besides the file's own ``synonyms``
    (a group in both gets the union of the phrases).
    """
    if not isinstance(data, dict) or not isinstance(data.get("skills", []), list):
        raise ConfigError("templates must be a mapping with a 'skills' list")
    raw_synonyms = data.get("synonyms", {}) or {}
    if not isinstance(raw_synonyms, dict) or not all(isinstance(v, list) for v in raw_synonyms.values()):
        raise ConfigError("templates 'synonyms' must map group names to lists of phrases")
    odd = [
        k
        for k, v in raw_synonyms.items()
        for w in (k, *v)
        if not isinstance(w, str | int | float) or isinstance(w, bool)
    ]
    if odd:
        raise ConfigError(
            f"templates synonym groups {sorted(set(map(str, odd)))} hold a non-text entry (YAML reads "
            "bare on/off/yes/no as booleans: quote them)"
        )
    own = {str(k).lower(): tuple(" ".join(str(p).lower().split()) for p in v) for k, v in raw_synonyms.items()}
    synonyms = _merge_synonyms(base_synonyms or {}, own)
    skills = []
    for i, entry in enumerate(data.get("skills", [])):
        if not isinstance(entry, dict) or "skill" not in entry or "patterns" not in entry:
            raise ConfigError(f"templates skills[{i}] needs 'skill' and 'patterns', got {entry!r}")
        skills.append(
            SkillTemplate(
                str(entry["skill"]),
                tuple(str(p) for p in entry["patterns"]),
                tuple(str(t) for t in entry.get("tasks", [])),
                tuple(str(e) for e in entry.get("examples", [])),
                synonyms,
                tuple(str(p) for p in entry.get("places", [])),
            )
        )
    lists = {key: _string_list(data, key) for key in _WORD_LISTS}
    if "determiners" not in data:
        lists["determiners"] = tuple(sorted(ARTICLES))
    return TemplateSet(tuple(skills), synonyms=synonyms, **lists)


def _builtin_data() -> dict[str, Any]:
    """The parsed YAML of the built-in ``templates.yaml``."""
    source = resources.files("abm.language").joinpath("templates.yaml")
    data: dict[str, Any] = parse_yaml(source.read_text(encoding="utf-8"), str(source), "template file") or {}
    return data


def load_templates(path: str | Path | None = None, base_synonyms: Synonyms | None = None) -> TemplateSet:
    """Load templates from a YAML file; ``None`` loads the built-in ``templates.yaml``.

    A user file may use the synonym groups of ``base_synonyms`` (default: the built-in groups, ``<put>``,
    ``<grasp>``, ...) besides its own.
    """
    if path is None:
        return _with_benchmark_tasks(parse_templates(_builtin_data(), base_synonyms))
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"template file not found: {path}")
    if base_synonyms is None:
        builtin = _builtin_data().get("synonyms", {}) or {}
        base_synonyms = {str(k): tuple(str(p) for p in v) for k, v in builtin.items()}
    data = load_yaml(path, "template file") or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a template file is a mapping (skills, synonyms, ...), not {type(data).__name__}")
    unknown = sorted(str(k) for k in data if k not in {"skills", "synonyms", *_WORD_LISTS})
    if unknown:
        raise ConfigError(f"{path}: unknown keys {unknown} (expected: {sorted({'skills', 'synonyms', *_WORD_LISTS})})")
    try:
        return parse_templates(data, base_synonyms)
    except ValueError as err:
        raise ConfigError(f"{path}: {err}") from None


def _with_benchmark_tasks(templates: TemplateSet) -> TemplateSet:
    """``templates`` with the skills the benchmark's tasks declare (``Task.skills``: entries of this file's form)
    tried first, and every skill naming the tasks that use it: each task of :data:`abm.sim.tasks.TASKS` whose own
    instruction templates parse to the skill. So a task names its skill nowhere but in its own module (a task whose
    instructions parse to no skill names none, and its tests say so)."""
    from abm.sim.tasks import TASKS  # the benchmark's tasks (sim, below language): with the built-in templates only

    declared = [dict(entry) for task in TASKS.values() for entry in task.skills]
    if declared:
        try:
            own = parse_templates({"skills": declared}, templates.synonyms)
        except ValueError as err:
            raise ConfigError(f"a task's skills (Task.skills): {err}") from None
        templates = templates.merged(own)
    parser = TemplateParser(templates)
    users: dict[str, tuple[str, ...]] = {}
    for name, task in TASKS.items():
        for text in task.templates:
            try:
                skill = parser.parse(text.format(target="thing", container="box")).skill
            except InstructionError:
                continue
            users[skill] = _union(users.get(skill, ()), (name,))
    skills = tuple(dataclasses.replace(t, tasks=_union(t.tasks, users.get(t.skill, ()))) for t in templates.skills)
    return dataclasses.replace(templates, skills=skills)


def _phrase_regex(phrases: Collection[str], lookahead: str = "") -> re.Pattern[str] | None:
    """`` (phrase1|phrase2|...) `` between words (longest first), optionally followed by ``lookahead``."""
    options = sorted({" ".join(p.split()) for p in phrases if p.strip()}, key=len, reverse=True)
    if not options:
        return None
    return re.compile(rf" (?:{'|'.join(re.escape(o) for o in options)}) {lookahead}")


def _destination_phrases(templates: TemplateSet) -> frozenset[str]:
    """The phrases naming a skill's place where things go (the plate, the target pad, the frypan; not a
    :data:`CARRIED_PLACES` part): each place of a skill, and the phrases of the synonym group named after it
    (``<target>``, ``<top_shelf>``, ``<pan>``), without articles."""
    places = {p for s in templates.skills for p in s.places if p not in CARRIED_PLACES}
    heads = {p.split()[-1] for p in places if p.split()}
    phrases = set(places)
    for group, options in templates.synonyms.items():
        last = group.replace("_", " ").split()[-1:]
        if last and any(h == last[0] or h.endswith(last[0]) for h in heads):
            phrases.update(options)
    return frozenset(p for p in (_drop_words(p, ARTICLES) for p in phrases) if p and p not in CARRIED_PLACES)


def _starts_with(words: list[str], phrases: Collection[str]) -> int:
    """Length (in words) of the longest phrase ``words`` starts with; 0 if none."""
    lengths = [len(p.split()) for p in phrases if p.split() and words[: len(p.split())] == p.split()]
    return max(lengths, default=0)


class TemplateParser:
    """Template-based :class:`InstructionParser` (the default).

    Parsing is deterministic: normalise (:func:`normalize_instruction`), fold a two-clause form
    ("pick up X and put it on the target" -> "put X on target"), match the skill patterns, and refuse
    what cannot be one skill on one named object: several steps, several objects ("all", "X and the
    Y"), a pronoun instead of an object, a grasp without a goal, or text no pattern matches. Refusals
    are :class:`InstructionError` (:class:`MultiStepInstructionError` for several steps or objects)
    whose message says what was not understood and lists accepted phrasings.
    """

    def __init__(self, templates: TemplateSet | None = None) -> None:
        self.templates = templates if templates is not None else load_templates()
        t = self.templates
        self._lead_words = frozenset(w for s in t.skills for w in s.lead_words) | frozenset(
            p.split()[0] for p in t.synonyms.get(GRASP_GROUP, ()) if p.split()
        )
        lead = "|".join(re.escape(w) for w in sorted(self._lead_words, key=len, reverse=True))
        self._step_split = _phrase_regex(t.step_words)
        joins = [j for j in t.clause_joins if j not in t.step_words]
        self._join_split = _phrase_regex(joins, rf"(?=(?:{lead})(?: |$))") if lead else None
        self._destinations = _destination_phrases(t)

    @classmethod
    def from_files(cls, *paths: str | Path, include_builtin: bool = True) -> TemplateParser:
        """Parser over the built-in templates (optional) extended by the given YAML files."""
        templates = load_templates() if include_builtin else TemplateSet(())
        for p in paths:
            templates = templates.merged(load_templates(p))
        return cls(templates)

    def with_templates(self, extra: TemplateSet | dict[str, Any] | str | Path) -> TemplateParser:
        """A new parser whose templates are extended by ``extra`` (tried first)."""
        if isinstance(extra, dict):
            extra = parse_templates(extra, self.templates.synonyms)
        elif isinstance(extra, str | Path):
            extra = load_templates(extra, self.templates.synonyms)
        return TemplateParser(self.templates.merged(extra))

    @property
    def skills(self) -> list[str]:
        """All known skill texts."""
        return [t.skill for t in self.templates.skills]

    def normalize(self, instruction: str) -> str:
        """The text the patterns are matched against (see :func:`normalize_instruction`)."""
        t = self.templates
        return normalize_instruction(instruction, t.polite_prefixes, t.polite_suffixes, {*t.determiners, *t.fillers})

    def parse(self, instruction: str, *, names: Collection[str] = ()) -> ParsedInstruction:
        """Decompose ``instruction`` into X and a skill.

        Args:
            instruction: the text.
            names: the scene's object names, if known: their words never count as a negation, condition,
                alternative or exclusion (an object called "either box").

        Raises:
            NotOneCommandError: not one positive command (:func:`check_one_command`), or a skill's place named as
                X, the thing to carry ("put the plate in the ketchup"); one line quoting the words.
            MultiStepInstructionError: several steps, or several / unspecified objects.
            InstructionError: anything else that is not one known skill on one named object.
        """
        check_one_command(instruction, names)
        t = self.templates
        words = _clean_words(instruction, t.polite_prefixes, t.polite_suffixes)
        dropped = {*t.determiners, *t.fillers}
        normalized = " ".join(w for w in words if w not in dropped)
        if not normalized or normalized in {*t.polite_prefixes, *t.polite_suffixes}:
            raise self._refusal(instruction, normalized, "nothing is left once polite words and articles are removed")
        candidates = [*self._folds(normalized), normalized]
        for candidate in (normalized, *candidates[:-1]):
            steps = self._steps(candidate)
            if len(steps) > 1:
                listed = "; ".join(f"{s.replace(PLACEHOLDER, x)!r}" for s, x in steps)
                one_by_one = "', then '".join(s.replace(PLACEHOLDER, f"the {x}") for s, x in steps)
                raise self._refusal(
                    instruction,
                    normalized,
                    f"it asks for {len(steps)} steps ({listed}), but abm runs one skill per instruction: give "
                    f"them one at a time, e.g. '{one_by_one}'",
                    MultiStepInstructionError,
                )
        for candidate in candidates:
            best = self._match(candidate)
            if best is None:
                continue
            template, target, second = best
            for obj in (target,) if second is None else (target, second):
                if obj in t.pronouns:
                    example = template.examples[0] if template.examples else template.skill
                    raise self._refusal(
                        instruction,
                        normalized,
                        f"{obj!r} does not say which object to use; name the object, e.g. {example!r}",
                    )
                quantifiers = [w for w in obj.split() if w in t.quantifiers]
                if quantifiers:
                    raise self._quantifier_refusal(instruction, normalized, quantifiers[0])
                if self._several_objects(words, obj):
                    raise self._refusal(
                        instruction,
                        normalized,
                        f"{obj!r} names several objects; abm moves one "
                        "object per instruction: give one instruction per object",
                        MultiStepInstructionError,
                    )
            if target in self._destinations:  # "put the plate in the ketchup": the place as the thing to carry
                raise NotOneCommandError(instruction, swapped(target, second or ""))
            return ParsedInstruction(instruction, target, template.skill, template.tasks, second)
        self._refuse_unmatched(instruction, normalized)

    __call__ = parse

    # -- matching ------------------------------------------------------------------------------------

    def _match(self, text: str) -> tuple[SkillTemplate, str, str | None] | None:
        """The most specific ``(template, X, Y)`` matching ``text`` whose X (and Y) are plausible objects.

        X may be a bare pronoun ("put it in the plate": a step of a multi-step request; :meth:`parse`
        refuses it on its own), but not contain one ("butter and put it": a mis-split two-clause form),
        nor a sequencing word or a further step ("red peg and then close jar").
        """
        pronouns = set(self.templates.pronouns)

        def plausible(target: str) -> bool:
            if target in pronouns:
                return True
            if pronouns.intersection(target.split()):
                return False
            if self._step_split is not None and self._step_split.search(f" {target} "):
                return False
            return not any(self._match(p) for p in self._split(target)[1:])

        best: tuple[SkillTemplate, SlotMatch] | None = None
        for template in self.templates.skills:
            m = template.match(text, plausible)
            if m is not None and m.target and m.second != "" and (best is None or m.specificity > best[1].specificity):
                best = (template, m)
        return None if best is None else (best[0], best[1].target, best[1].second)

    def _folds(self, normalized: str) -> list[str]:
        """Two-clause forms read as one clause: "pick up X [up] and put it on target" -> "put X on target"."""
        t = self.templates
        words = normalized.split()
        start = _starts_with(words, t.synonyms.get(GRASP_GROUP, ()))
        if not start:
            return []
        folds = []
        joins = [j.split() for j in t.clause_joins if j.split()]
        for k in range(start + 1, len(words)):
            for join in sorted(joins, key=len, reverse=True):
                if words[k : k + len(join)] != join:
                    continue
                obj = words[start:k]
                if obj and obj[-1] == "up":
                    obj = obj[:-1]
                rest = words[k + len(join) :]
                at = next((i for i, w in enumerate(rest) if w in t.pronouns), None)
                if obj and at is not None:
                    folds.append(" ".join([*rest[:at], *obj, *rest[at + 1 :]]))
                break
        return folds

    def _split(self, text: str) -> list[str]:
        """``text`` cut at sequencing words, and at clause joins followed by a skill's leading verb."""
        parts = [text]
        for regex in (self._step_split, self._join_split):
            if regex is not None:
                parts = [q.strip() for p in parts for q in regex.split(f" {p} ")]
        return [p for p in parts if p]

    def _steps(self, normalized: str) -> list[tuple[str, str]]:
        """``(skill, X)`` of each step of a multi-step request, if it has several and every one parses."""
        parts = self._split(normalized)
        if len(parts) < 2:
            return []
        steps = []
        for part in parts:
            m = self._match(part)
            if m is None:
                return []
            skill = m[0].skill if m[2] is None else re.sub(rf"\b{SECOND_PLACEHOLDER}\b", m[2], m[0].skill)
            steps.append((skill, m[1]))
        return steps

    def _several_objects(self, words: list[str], target: str) -> bool:
        """Whether X joins two noun phrases, each with its own determiner ("the red block and the blue block")."""
        x = target.split()
        dets = set(self.templates.determiners)
        for i, w in enumerate(x[:-1]):
            if w != "and":
                continue
            after = x[i + 1]
            if any(
                a == "and" and b in dets and c == after for a, b, c in zip(words, words[1:], words[2:], strict=False)
            ):
                return True
        return False

    # -- refusals ------------------------------------------------------------------------------------

    def _refuse_unmatched(self, instruction: str, normalized: str) -> NoReturn:
        """Raise the most specific refusal for an instruction that no pattern matches."""
        t = self.templates
        folds = self._folds(normalized)
        if folds and len(self._split(folds[0])) == 1:  # one action in two clauses, just not a known one
            raise self._refusal(instruction, normalized, f"it reads as {folds[0]!r}, which no skill template matches")
        parts = self._split(normalized)
        if len(parts) > 1 and self._step_split is not None and self._step_split.search(f" {normalized} "):
            unknown = [p for p in parts if self._match(p) is None]
            listed = "; ".join(repr(p) for p in parts)
            be = "is" if len(unknown) == 1 else "are"
            raise self._refusal(
                instruction,
                normalized,
                f"it asks for {len(parts)} steps ({listed}), but abm runs one skill per instruction (and "
                f"{', '.join(repr(p) for p in unknown)} {be} no skill it knows)",
                MultiStepInstructionError,
            )
        words = normalized.split()
        start = _starts_with(words, t.synonyms.get(GRASP_GROUP, ()))
        verb = start or (1 if words[0] in self._lead_words else 0)
        if verb and words[verb:] and words[verb] in t.quantifiers:  # "stack all blocks", "pick up every jar"
            raise self._quantifier_refusal(instruction, normalized, words[verb])
        obj = words[start:-1] if words[-1:] == ["up"] else words[start:]
        if start and obj and len(parts) == 1:
            x = " ".join(obj)
            goals = [s.skill.replace(PLACEHOLDER, f"the {x}") for s in t.skills if s.skill.split()[1:2] == ["X"]]
            suggested = ", ".join(repr(g) for g in goals[:3])
            raise self._refusal(
                instruction,
                normalized,
                f"it reads as picking up {x!r} without saying what to do with it; say where it goes, e.g. {suggested}",
            )
        raise self._refusal(instruction, normalized, "no skill template matches it")

    def _quantifier_refusal(self, instruction: str, normalized: str, word: str) -> InstructionError:
        """The refusal of a request for several or unspecified objects ("all", "every", "something")."""
        reason = f"{word!r} asks for several or unspecified objects; abm moves one named object per instruction"
        return self._refusal(instruction, normalized, reason, MultiStepInstructionError)

    def _refusal(
        self, instruction: str, normalized: str, reason: str, kind: type[InstructionError] = InstructionError
    ) -> InstructionError:
        """An error naming what was not understood, the known skills with example phrasings, and remedies."""
        lines = []
        for s in self.templates.skills:
            examples = "; ".join(repr(e) for e in s.examples[:2])
            lines.append(f"  {s.skill}" + (f"  (e.g. {examples})" if examples else ""))
        known = "\n".join(lines)
        if issubclass(kind, MultiStepInstructionError):  # a rewriter must not merge steps: RewritingParser re-raises
            remedy = "Give one skill on one named object per instruction, one instruction after the other."
        else:
            remedy = (
                "Rephrase it like one of these, add templates (load_templates / TemplateParser.with_templates), "
                "or use RewritingParser with a language-model rewriter."
            )
        return kind(
            f"cannot understand instruction {instruction!r} (normalised: {normalized!r}): {reason}.\n"
            f"Known skills, one object per instruction:\n{known}\n"
            "Also accepted: polite wrappers ('could you ...', 'please', '... for me'), missing articles, verb "
            "synonyms (grab/take/lift, place/set/drop, shut) and two clauses such as 'pick up the red block and "
            f"put it on the target'.\n{remedy}"
        )


class RewritingParser:
    """Parser that first rewrites free-form text with a user-supplied function, then uses templates.

    ``rewrite`` is any callable ``str -> str``, e.g. a wrapper around a language model prompted with
    the known skills (``parser.skills``) to restate the instruction as one of them. The template
    parser is tried on the original text first, so the rewriter only runs when needed.
    """

    def __init__(self, rewrite: Callable[[str], str], base: TemplateParser | None = None) -> None:
        self.rewrite = rewrite
        self.base = base if base is not None else TemplateParser()

    @property
    def skills(self) -> list[str]:
        return self.base.skills

    def parse(self, instruction: str) -> ParsedInstruction:
        try:
            return self.base.parse(instruction)
        except MultiStepInstructionError:
            raise  # several skills: rewriting them into one would drop a step
        except InstructionError:
            rewritten = self.rewrite(instruction)
        parsed = self.base.parse(rewritten)
        return ParsedInstruction(instruction, parsed.target, parsed.skill, parsed.tasks)


_DEFAULT_PARSER: TemplateParser | None = None


def default_parser() -> TemplateParser:
    """The process-wide parser over the built-in templates."""
    global _DEFAULT_PARSER
    if _DEFAULT_PARSER is None:
        _DEFAULT_PARSER = TemplateParser()
    return _DEFAULT_PARSER


def decompose_instruction(instruction: str, parser: InstructionParser | None = None) -> tuple[str, str]:
    """``instruction`` -> ``(X, skill)``.

    ``"put the tomato in the plate"`` -> ``("tomato", "put X in the plate")``; raises
    :class:`InstructionError` (a ``ValueError``) when no template matches.
    """
    parsed = (parser or default_parser()).parse(instruction)
    return parsed.target, parsed.skill
