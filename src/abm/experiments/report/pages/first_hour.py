"""The first-hour blocks: the README's measured times and reproducibility, its speed table, and docs/evaluation.md's
measured quickstart run, written from ``abm/configs/measured.json`` (:mod:`abm.measured`) between their markers."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from abm import measured
from abm.experiments.report.files import replace_between

README_START, README_END = "<!-- first_hour:start -->", "<!-- first_hour:end -->"
EVAL_START, EVAL_END = "<!-- quickstart_measured:start -->", "<!-- quickstart_measured:end -->"
SPEED_START, SPEED_END = "<!-- speed:start -->", "<!-- speed:end -->"
SOURCE = "generated from src/abm/configs/measured.json by `python benchmarks/first_hour.py`"
SPEED_SOURCE = "generated from src/abm/configs/measured.json by `python benchmarks/first_hour.py --speed`"


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


@dataclass(frozen=True)
class SpeedRow:
    """One row of the README's speed table: what is measured, the command that measures it (run by
    ``benchmarks/first_hour.py --speed`` exactly as shown; ``None``: the row above's command), the result from the
    ``speed`` section's values, and the paper's number where it gives one."""

    label: str
    command: str | None
    result: Callable[[dict[str, Any]], str]
    paper: str = "—"


MASK_FIELD_DOC = "docs/performance.md#the-mask-field-on-2-cpu-cores"
SPEED_ROWS: tuple[SpeedRow, ...] = (
    SpeedRow("render 5 × 220² virtual views from 100k points", "python benchmarks/render_speed.py",
             lambda v: f"{v['render_ms']:.1f} ms"),
    SpeedRow("one policy step, `small` (fuse + ground + render + model + decode)",
             "python benchmarks/policy_speed.py --presets small paper",
             lambda v: f"{v['policy_small_s']:.2f} s ({1 / v['policy_small_s']:.1f} FPS)"),
    SpeedRow("one policy step, `paper` size, CPU", None,
             lambda v: f"{v['policy_paper_s']:.2f} s ({1 / v['policy_paper_s']:.2f} FPS; "
                       f"{v['paper_parameters'] / 1e6:.1f} M parameters)", "0.68 FPS"),
    SpeedRow("mask field, 4 cameras 128², ViT-B/16 (random weights, the real architecture)",
             "python benchmarks/grounding_speed.py --models vit-b16 --repeats 5",
             lambda v: f"{v['mask_field_s']:.2f} s ([where the time goes]({MASK_FIELD_DOC}))",
             "~1 s (ViT-L, 0.98 FPS)"),
    SpeedRow("training throughput, `small`, batch 8", "python benchmarks/train_speed.py --preset small --batch 8",
             lambda v: f"{v['train_samples_per_s']:.1f} samples/s"),
    SpeedRow("demonstration generation, 128², 2 workers", "python benchmarks/generation_throughput.py",
             lambda v: "{:.0f}–{:.0f} episodes/min (by task)".format(*v["generation_episodes_per_min"])),
)


def speed_block() -> str:
    """The README's speed table, from the ``speed`` section (every command run one after another on one machine,
    torch's default threads, nothing else running)."""
    sp = measured.measured().get("speed")
    if not sp:
        return "The speed table is not measured yet (`python benchmarks/first_hour.py --speed`).\n"
    rows = "".join(f"| {r.label} | {f'`{r.command}`' if r.command else 'same'} | {r.result(sp)} | {r.paper} |\n"
                   for r in SPEED_ROWS)
    return (f"Measured ({SPEED_SOURCE}) on {sp['machine']}, "
            f"{sp['date']}, at {sp['commit']}, each command alone on the machine with torch's default threads:\n\n"
            "| measurement | command | result | paper (RTX 3090) |\n|---|---|---|---|\n" + rows)


def write(root: Path) -> list[Path]:
    """Rewrite the blocks under ``root`` (the checkout); the files written."""
    blocks = {"README.md": [(README_START, README_END, readme_block()), (SPEED_START, SPEED_END, speed_block())],
              "docs/evaluation.md": [(EVAL_START, EVAL_END, quickstart_block())]}
    written = []
    for name, replacements in blocks.items():
        path = root / name
        text = new = path.read_text()
        for start, end, body in replacements:
            new = replace_between(new, start, end, body, name)
        if new != text:
            path.write_text(new)
            written.append(path)
    return written
