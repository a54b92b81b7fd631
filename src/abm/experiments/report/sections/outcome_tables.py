"""The ``outcome_tables`` report section: per split, the tables `abm eval` wrote for every run."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Per split, the tables ``abm eval`` wrote (``results.md``, kept as ``RUN_SPLIT.md``) of every run."""
    out = []
    for split in section.splits or tuple(s.split for s in ctx.spec.evaluation.splits):
        tables = []
        for name in ctx.spec.runs:
            path = ctx.layout.eval_dir(name, split) / "results.md"
            if path.is_file():
                tables.append("\n".join(line for line in path.read_text().strip().splitlines()
                                        if "report.html" not in line).strip())
        if tables:
            out += [f"## {split}", *tables]
    return out
