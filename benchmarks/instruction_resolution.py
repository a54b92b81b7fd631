"""How often instructions in plain words resolve to the right scene object and task: the template parser alone
(before) against :func:`abm.language.resolve_instruction` (after), on the hand-written set
``tests/data/free_instructions.yaml`` (issue 40 item 4; recorded in docs/grounding.md).

A case is *right* when the answer's object is the expected one of the scene and its task the expected task
(and, where given, the container Y and the shelf level); *wrong* when an answer is given but is not right; and
*refused* when the instruction is refused. For the template parser alone, the answer's object is what
``abm run`` would act on: its X when exactly one scene object has that name
(:func:`abm.grounding.decision.target_candidates`), and the task counts when it is among the skill's tasks.

Usage: ``.venv/bin/python benchmarks/instruction_resolution.py [--cases FILE] [--show]``
"""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from abm.files import load_yaml
from abm.grounding.decision import target_candidates
from abm.language.instruction import InstructionError, default_parser
from abm.language.resolve import resolve_instruction

CASES = Path(__file__).resolve().parents[1] / "tests" / "data" / "free_instructions.yaml"
SHELF_SKILLS = {"top": "put X on the top shelf", "bottom": "put X on the bottom shelf"}


@dataclass(frozen=True)
class Case:
    """One instruction with its scene and the expected answer (``target`` empty: it must be refused)."""

    text: str
    scene: tuple[str, ...]
    target: str = ""
    task: str = ""
    second: str | None = None
    level: str | None = None


def load_cases(path: str | Path = CASES) -> tuple[list[Case], list[Case], list[Case]]:
    """``(cases, held-out cases, refusals)`` of a case file."""
    data: dict[str, Any] = load_yaml(path, "instruction cases")
    scenes = {name: tuple(objects) for name, objects in data["scenes"].items()}

    def case(entry: dict[str, Any]) -> Case:
        return Case(entry["text"], scenes[entry["scene"]], entry.get("target", ""), entry.get("task", ""),
                    entry.get("second"), entry.get("level"))

    return ([case(e) for e in data["cases"]], [case(e) for e in data.get("holdout", [])],
            [case(e) for e in data.get("refusals", [])])


def judge_resolver(case: Case) -> tuple[str, str]:
    """``(verdict, answer)`` of :func:`resolve_instruction`: verdict ``right``, ``wrong`` or ``refused``."""
    try:
        r = resolve_instruction(case.text, case.scene)
    except InstructionError:
        return "refused", ""
    ok = (r.target == case.target and r.task == case.task and r.second == case.second
          and (case.level is None or r.skill == SHELF_SKILLS[case.level]))
    return ("right" if ok else "wrong"), f"{r.canonical} ({r.task}, {r.confidence:.2f}, {r.method})"


def judge_templates(case: Case) -> tuple[str, str]:
    """``(verdict, answer)`` of the template parser alone (module docstring)."""
    try:
        p = default_parser().parse(case.text)
    except InstructionError:
        return "refused", ""
    names = dict(enumerate(case.scene))
    x = target_candidates(p.target, names)
    y = target_candidates(p.second, names) if p.second is not None else ()
    ok = (x == (case.target,) and case.task in p.tasks
          and (case.second is None or y == (case.second,))
          and (case.level is None or p.skill == SHELF_SKILLS[case.level]))
    return ("right" if ok else "wrong"), f"X={p.target!r} Y={p.second!r} skill={p.skill!r}"


def tally(cases: list[Case], judge: Any) -> Counter[str]:
    """Verdict counts of ``judge`` over ``cases``."""
    return Counter(judge(c)[0] for c in cases)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=Path, default=CASES)
    ap.add_argument("--show", action="store_true", help="print every case's answers")
    args = ap.parse_args()
    cases, holdout, refusals = load_cases(args.cases)
    if args.show:
        for c in cases + holdout:
            (bv, ba), (av, aa) = judge_templates(c), judge_resolver(c)
            print(f"{bv:>7} -> {av:<7} {c.text!r}: {aa or ba}")
    print(f"{len(cases)} + {len(holdout)} held-out instructions in plain words ({args.cases.name}), "
          f"{len(refusals)} that must be refused\n")
    print("| set | parser | right | wrong | refused |\n|---|---|---|---|---|")
    for name, group in (("written with the resolver", cases), ("held out", holdout), ("all", cases + holdout)):
        n = len(group)
        for label, judge in (("templates alone (before)", judge_templates),
                             ("resolve_instruction (after)", judge_resolver)):
            t = tally(group, judge)
            print(f"| {name} | {label} | {t['right']}/{n} ({100 * t['right'] / n:.0f}%) | {t['wrong']} | "
                  f"{t['refused']} |")
    answered = [c.text for c in refusals if judge_resolver(c)[0] != "refused"]
    print(f"\nrefusals kept: {len(refusals) - len(answered)}/{len(refusals)}"
          + (f" (answered: {answered})" if answered else ""))


if __name__ == "__main__":
    main()
