"""Instruction decomposition: instruction -> (target object description X, skill text with "X").

ABM splits every instruction into the object to ground (X, e.g. ``"tomato"``) and the robot skill
the policy conditions on (e.g. ``"put X in the plate"``). The split is done by templates kept as data
(``templates.yaml`` in this package); users extend them with :func:`load_templates` or
:meth:`TemplateParser.with_templates`. Any other parser (e.g. one backed by a language model that
rewrites free-form text into a known template) plugs in through the :class:`InstructionParser`
protocol; :class:`RewritingParser` shows the shape of such a parser without shipping a network client.

Matching is done on a *normalised* instruction: lower case, punctuation removed, whitespace collapsed,
polite prefixes/suffixes ("please", "could you", ...) and the articles a/an/the dropped. Compositional
instructions reuse trained skills because colour words and nouns such as "block" all stay inside X:
"put the red block in the plate" -> ("red block", "put X in the plate").
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Protocol, runtime_checkable

import yaml

PLACEHOLDER = "X"
ARTICLES: frozenset[str] = frozenset({"a", "an", "the"})
_VOWELS = "aeiou"


class InstructionError(ValueError):
    """An instruction that no template matches (the message lists the known skills)."""


class MultiStepInstructionError(InstructionError):
    """An instruction that asks for several skills in a row; abm runs one skill per instruction."""


@dataclass(frozen=True)
class ParsedInstruction:
    """The result of decomposing one instruction.

    Attributes:
        instruction: the original text.
        target: the object description X (lower case, no articles), e.g. ``"red block"``.
        skill: the skill text with the placeholder, e.g. ``"put X in the plate"``.
        tasks: benchmark tasks that use this skill (informative only).
    """

    instruction: str
    target: str
    skill: str
    tasks: tuple[str, ...] = ()

    @property
    def prompt(self) -> str:
        """The CLIP text prompt for X: ``"a photo of a X"`` / ``"a photo of an X"``."""
        return clip_prompt(self.target)


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


@dataclass(frozen=True)
class SkillTemplate:
    """One skill and the patterns that recognise it (see ``templates.yaml`` for the syntax)."""

    skill: str
    patterns: tuple[str, ...]
    tasks: tuple[str, ...] = ()
    _compiled: tuple[tuple[re.Pattern[str], int], ...] = field(default=(), repr=False, compare=False)

    def __post_init__(self) -> None:
        if PLACEHOLDER not in self.skill.split():
            raise ValueError(f"skill {self.skill!r} must contain the placeholder word {PLACEHOLDER!r}")
        if not self.patterns:
            raise ValueError(f"skill {self.skill!r} has no patterns")
        object.__setattr__(self, "_compiled", tuple(_compile_pattern(p) for p in self.patterns))

    def match(self, normalized: str) -> tuple[str, int] | None:
        """``(X, specificity)`` of the most specific pattern matching ``normalized``, else ``None``."""
        best: tuple[str, int] | None = None
        for regex, literals in self._compiled:
            m = regex.fullmatch(" " + normalized)
            if m and (best is None or literals > best[1]):
                best = (m.group("X").strip(), literals)
        return best


def _compile_pattern(pattern: str) -> tuple[re.Pattern[str], int]:
    """Pattern text -> (regex over ``" " + normalised text``, number of required literal tokens)."""
    tokens = re.findall(r"\{x\}|\([^)]*\)|\[[^\]]*\]|[^\s()\[\]{}]+", pattern.lower())
    if tokens.count("{x}") != 1:
        raise ValueError(f"pattern {pattern!r} must contain {{X}} exactly once")
    regex = ""
    literals = 0
    for tok in tokens:
        if tok == "{x}":
            regex += r" (?P<X>\S+(?: \S+)*?)"
            continue
        optional = tok.startswith("[")
        raw = tok[1:-1].split("|") if tok.startswith(("(", "[")) else [tok]
        options = sorted({o for o in (_drop_articles(r) for r in raw) if o}, key=len, reverse=True)
        if not options:
            continue
        alternatives = "|".join(re.escape(o) for o in options)
        regex += f"(?: (?:{alternatives}))?" if optional else f" (?:{alternatives})"
        literals += 0 if optional else 1
    return re.compile(regex), literals


def _drop_articles(text: str) -> str:
    return " ".join(w for w in text.split() if w not in ARTICLES)


def normalize_instruction(
    text: str, prefixes: Sequence[str] = (), suffixes: Sequence[str] = ()
) -> str:
    """Lower-case, strip punctuation, polite prefixes/suffixes and articles; collapse spaces.

    ``"Please, put the Cream Cheese in a plate!"`` -> ``"put cream cheese in plate"``.
    """
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
                words = words[len(p):]
                changed = True
                break
        for p in suffix_words:
            if p and words[-len(p):] == p and len(words) > len(p):
                words = words[: -len(p)]
                changed = True
                break
    return " ".join(w for w in words if w not in ARTICLES)


@dataclass(frozen=True)
class TemplateSet:
    """Skill templates plus the polite prefixes/suffixes dropped before matching."""

    skills: tuple[SkillTemplate, ...]
    polite_prefixes: tuple[str, ...] = ()
    polite_suffixes: tuple[str, ...] = ()

    def merged(self, other: TemplateSet) -> TemplateSet:
        """A new set with ``other``'s skills tried first (patterns of the same skill text are merged)."""
        by_skill: dict[str, SkillTemplate] = {}
        for t in (*other.skills, *self.skills):
            if t.skill in by_skill:
                old = by_skill[t.skill]
                by_skill[t.skill] = SkillTemplate(
                    t.skill, tuple(dict.fromkeys((*old.patterns, *t.patterns))),
                    tuple(dict.fromkeys((*old.tasks, *t.tasks))),
                )
            else:
                by_skill[t.skill] = t
        return TemplateSet(
            tuple(by_skill.values()),
            tuple(dict.fromkeys((*self.polite_prefixes, *other.polite_prefixes))),
            tuple(dict.fromkeys((*self.polite_suffixes, *other.polite_suffixes))),
        )


def parse_templates(data: dict) -> TemplateSet:
    """Build a :class:`TemplateSet` from the YAML structure (``skills``, optional polite words)."""
    if not isinstance(data, dict) or not isinstance(data.get("skills", []), list):
        raise ValueError("templates must be a mapping with a 'skills' list")
    skills = []
    for i, entry in enumerate(data.get("skills", [])):
        if not isinstance(entry, dict) or "skill" not in entry or "patterns" not in entry:
            raise ValueError(f"templates skills[{i}] needs 'skill' and 'patterns', got {entry!r}")
        skills.append(SkillTemplate(str(entry["skill"]), tuple(str(p) for p in entry["patterns"]),
                                    tuple(str(t) for t in entry.get("tasks", []))))
    return TemplateSet(tuple(skills), tuple(data.get("polite_prefixes", [])),
                       tuple(data.get("polite_suffixes", [])))


def load_templates(path: str | Path | None = None) -> TemplateSet:
    """Load templates from a YAML file; ``None`` loads the built-in ``templates.yaml``."""
    if path is None:
        text = resources.files("abm.grounding").joinpath("templates.yaml").read_text(encoding="utf-8")
    else:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"template file not found: {path}")
        text = path.read_text(encoding="utf-8")
    return parse_templates(yaml.safe_load(text) or {})


class TemplateParser:
    """Template-based :class:`InstructionParser` (the default)."""

    def __init__(self, templates: TemplateSet | None = None) -> None:
        self.templates = templates if templates is not None else load_templates()

    @classmethod
    def from_files(cls, *paths: str | Path, include_builtin: bool = True) -> TemplateParser:
        """Parser over the built-in templates (optional) extended by the given YAML files."""
        templates = load_templates() if include_builtin else TemplateSet(())
        for p in paths:
            templates = templates.merged(load_templates(p))
        return cls(templates)

    def with_templates(self, extra: TemplateSet | dict | str | Path) -> TemplateParser:
        """A new parser whose templates are extended by ``extra`` (tried first)."""
        if isinstance(extra, dict):
            extra = parse_templates(extra)
        elif isinstance(extra, str | Path):
            extra = load_templates(extra)
        return TemplateParser(self.templates.merged(extra))

    @property
    def skills(self) -> list[str]:
        """All known skill texts."""
        return [t.skill for t in self.templates.skills]

    def normalize(self, instruction: str) -> str:
        return normalize_instruction(instruction, self.templates.polite_prefixes,
                                     self.templates.polite_suffixes)

    def parse(self, instruction: str) -> ParsedInstruction:
        """Decompose ``instruction``; raises :class:`InstructionError` when no template matches."""
        normalized = self.normalize(instruction)
        steps = self._steps(normalized)
        if len(steps) > 1:
            listed = "; ".join(f"{p.skill.replace(PLACEHOLDER, p.target)!r}" for p in steps)
            raise MultiStepInstructionError(
                f"instruction {instruction!r} asks for {len(steps)} steps ({listed}); abm runs one skill per "
                "instruction: give the steps one at a time"
            )
        best: tuple[SkillTemplate, str, int] | None = None
        for template in self.templates.skills:
            m = template.match(normalized)
            if m is not None and m[0] and (best is None or m[1] > best[2]):
                best = (template, m[0], m[1])
        if best is None:
            known = "\n  ".join(self.skills)
            raise InstructionError(
                f"instruction {instruction!r} (normalised: {normalized!r}) matches no template; "
                f"known skills:\n  {known}\nAdd a template with abm.grounding.load_templates / "
                "TemplateParser.with_templates."
            )
        template, target, _ = best
        return ParsedInstruction(instruction, target, template.skill, template.tasks)

    __call__ = parse

    def _steps(self, normalized: str) -> list[ParsedInstruction]:
        """The skills of a multi-step request ("put X in the plate and then close Y"), if every part parses."""
        parts = [p for p in re.split(r"\s+(?:and then|then|and|after that|afterwards)\s+", normalized) if p]
        if len(parts) < 2:
            return []
        parsed = []
        for part in parts:
            try:
                parsed.append(self.parse(part))
            except InstructionError:
                return []
        return parsed


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


def decompose_instruction(
    instruction: str, parser: InstructionParser | None = None
) -> tuple[str, str]:
    """``instruction`` -> ``(X, skill)``.

    ``"put the tomato in the plate"`` -> ``("tomato", "put X in the plate")``; raises
    :class:`InstructionError` (a ``ValueError``) when no template matches.
    """
    parsed = (parser or default_parser()).parse(instruction)
    return parsed.target, parsed.skill
