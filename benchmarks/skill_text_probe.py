"""Skill-text probe: does a mask policy's keyframe follow its skill text?

A mask variant (abm, stack, concat-*) reads the target's mask and the instruction's skill text, the
instruction with the target replaced by X ("put X in the wine rack"). On a task's evaluation scenes (the
seeds of ``abm eval``), teacher-forced on the expert's rollout like ``benchmarks/keyframe_accuracy.py``,
the policy predicts one keyframe kind once with the scene's own instruction and once with every other
skill text of the benchmark's tasks, worded about the same target ("take the wine bottle off the frypan").
Per skill text the table gives the median position error (cm) against the expert's label and the median
distance (cm) from the prediction with the scene's own text. A policy that reads its text moves its
prediction when the text changes; one that stays put has not learned to tell those skills apart by their
text (e.g. because its language encoder gives them codes it could not separate), and then does whatever
the texts share.

Usage: python benchmarks/skill_text_probe.py --run models/abm_clip.pt --task place_wine --kind move
           [--episodes 5] [--split seen] [--resolution 128] [--grounder oracle] [--skill-tasks ...]
           [--out probe.json]

The experiment engine runs it in the diagnose stage of a spec whose ``diagnose:`` block has ``skill_text:``
(``configs/experiments/paper_tables_v2.yaml``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from abm.evaluation.keyframe_accuracy import skill_text_probe, task_skills
from abm.experiments.spec import load_spec
from abm.grounding.config import grounder_from_flags
from abm.machine import describe_machine
from abm.policy import KeyframePolicy

PAPER_TASKS = load_spec("paper_tables").data.tasks  # the paper's 8 tasks (configs/experiments/paper_tables.yaml)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", required=True, type=Path, help="a mask variant's run folder, checkpoint or zoo file")
    p.add_argument("--task", required=True)
    p.add_argument("--kind", default="move", help="the expert keyframe kind to probe (default move)")
    p.add_argument("--split", default="seen")
    p.add_argument("--episodes", type=int, default=5)
    p.add_argument("--resolution", type=int, default=128, help="camera pixels (as in training)")
    p.add_argument("--grounder", choices=["clip", "oracle", "tracking"], default=None,
                   help="override the checkpoint's grounder (oracle: the simulator's mask)")
    p.add_argument("--skill-tasks", nargs="+", default=list(PAPER_TASKS),
                   help="the tasks whose skill texts are tried (default: the paper's 8)")
    p.add_argument("--out", type=Path, default=None, help="write the rows as JSON")
    args = p.parse_args()

    policy = KeyframePolicy.from_checkpoint(args.run, grounder=grounder_from_flags(args.grounder))
    if policy.spec.language != "skill":
        raise SystemExit(f"{args.run} is a {policy.spec.name!r} policy: it reads the whole instruction, not a "
                         "skill text; the probe needs a mask variant (abm, stack, concat-*)")
    skills = task_skills(args.skill_tasks)
    start = time.perf_counter()
    rows = skill_text_probe(policy.act, args.task, args.split, args.episodes, args.kind, list(skills),
                            args.resolution)
    for r in rows:
        r["task"] = skills[str(r["skill"])]
    print(f"machine: {describe_machine()}; {args.run}, {args.task} {args.split}, keyframe {args.kind!r}, "
          f"grounder {args.grounder or 'of the checkpoint'}, {rows[0]['n']} keyframes; "
          f"{time.perf_counter() - start:.0f} s")
    print("| skill text | its task | position error cm (median) | moved from own text cm (median) |")
    print("|---|---|---|---|")
    for r in rows:
        name = f"**{r['skill']}** (own)" if r["own"] else r["skill"]
        print(f"| {name} | {r['task']} | {r['position_cm_median']:.1f} | {r['moved_cm_median']:.1f} |")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"machine": describe_machine(), "run": str(args.run), "task": args.task,
                                        "split": args.split, "kind": args.kind, "grounder": args.grounder,
                                        "rows": rows}, indent=1))
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
