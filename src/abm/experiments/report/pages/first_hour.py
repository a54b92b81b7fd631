"""The first-hour blocks: the README's measured times and reproducibility, and docs/evaluation.md's measured
quickstart run, written from ``abm/configs/measured.json`` (:mod:`abm.measured`) between their markers."""

from __future__ import annotations

from pathlib import Path

from abm import measured
from abm.experiments.report.files import replace_between

README_START, README_END = "<!-- first_hour:start -->", "<!-- first_hour:end -->"
EVAL_START, EVAL_END = "<!-- quickstart_measured:start -->", "<!-- quickstart_measured:end -->"
SOURCE = "generated from src/abm/configs/measured.json by `python benchmarks/first_hour.py`"


def readme_block() -> str:
    """The README's block: what the two commands and the zoo evaluation cost, and what reproduces where."""
    return (f"Measured ({SOURCE}): `abm quickstart` {measured.quickstart_text()}. `abm zoo eval` (the committed "
            f"models, no training): {measured.zoo_eval_text()}. The test script: {measured.tests_text()}. "
            f"`abm --help`: {measured.help_text()}. {measured.reproducibility_text()}\n")


def quickstart_block() -> str:
    """docs/evaluation.md's block: the measured quickstart run in a table."""
    q = measured.measured().get("quickstart")
    if not q:
        return "The quickstart is not measured yet.\n"
    methods = list(q["results"])
    head = " | ".join(f"{m} {split}" for m in methods for split in q["results"][m])
    cells = " | ".join(f"{s}/{n}" for m in methods for s, n in q["results"][m].values())
    return (f"**Measured** ({SOURCE}) with `time abm quickstart` on a fresh clone at {q['commit']}, {q['date']}, on "
            f"{q['machine']}, no GPU, grounded with the {q['grounder']}; {q['load']}.\n\n"
            f"| | {head} | wall | CPU |\n|{'---|' * (len(methods) * 2 + 3)}\n"
            f"| defaults | {cells} | {q['wall_minutes']:.1f} min | {q['cpu_minutes']:.1f} min |\n")


def write(root: Path) -> list[Path]:
    """Rewrite both blocks under ``root`` (the checkout); the files written."""
    written = []
    for name, start, end, body in (("README.md", README_START, README_END, readme_block()),
                                   ("docs/evaluation.md", EVAL_START, EVAL_END, quickstart_block())):
        path = root / name
        text = path.read_text()
        new = replace_between(text, start, end, body, name)
        if new != text:
            path.write_text(new)
            written.append(path)
    return written
