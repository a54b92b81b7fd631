"""The ``sentences`` report section: comparison sentences of two rows' averages."""

from __future__ import annotations

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import ratio
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """Each sentence whose two rows have both averages, one per line."""
    out = []
    for sentence in section.sentences:
        a, b = sentence.runs
        values = {f"{who}_{s}": ctx.average(run, s) for who, run in (("a", a), ("b", b)) for s in ("seen", "unseen")}
        if any(v is None for v in values.values()):
            continue
        shown = {k: f"{v:.0f}" for k, v in values.items()}
        out.append(sentence.text.format(a=a, b=b, **shown, ratio_seen=ratio(values["a_seen"], values["b_seen"]),
                                        ratio_unseen=ratio(values["a_unseen"], values["b_unseen"])))
    return ["\n".join(out)] if out else []
