"""The ``zoo_eval`` report section: the timed `abm zoo eval` and its table."""

from __future__ import annotations

import re

from abm.experiments.report.context import Context
from abm.experiments.spec import Section


def write(ctx: Context, section: Section) -> list[str]:
    """The timed ``abm zoo eval``, once it ran."""
    if ctx.outcomes.zoo_eval is None:
        return []
    table, seconds = ctx.outcomes.zoo_eval
    episodes = max((int(n) for n in re.findall(r"\(\d+/(\d+)\)", table)), default=0)
    head = next((line for line in table.splitlines() if line.startswith("| method |")), "")
    tasks = [c.strip() for c in head.strip("|").split("|")[1:] if c.strip() not in ("avg", "")]
    # a gated edition's models are not abm zoo eval's default before its gate opens (nor once a later edition's
    # is), so its command names them; the editions before the gate keep their pages' words
    models = [ctx.spec.zoo_name(r) for r in ctx.spec.evaluation.zoo_eval] if ctx.spec.report.readme_when else []
    command = "abm zoo eval" + (f" --tasks {' '.join(tasks)}" if tasks else "") + (
        f" --episodes {episodes}" if episodes else "") + (f" --models {' '.join(models)}" if models else "")
    each = f" ({', '.join(tasks)}; {episodes} episodes per task and split)" if tasks and episodes else ""
    return [f"Without training: `abm zoo eval` evaluates the zoo's abm and rvt models on seen and unseen objects "
            f"through the full pipeline. The table below{each} took {seconds / 60:.0f} min on this machine; "
            f"`{command}` reproduces it (the command's defaults are now the paper's 8 tasks at 5 episodes):"
            f"\n\n{table}"]
