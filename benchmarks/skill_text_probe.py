"""Skill-text probe: does a mask policy's keyframe follow its skill text?

The command line of the ``skill_text`` diagnosis (:class:`abm.evaluation.diagnose.skill_text.SkillTextProbe`,
which the experiment engine runs in the diagnose stage of a spec whose ``diagnose:`` block has ``skill_text:``,
e.g. ``configs/experiments/paper_tables_v2.yaml``). On a task's evaluation scenes, teacher-forced on the expert's
rollout, the policy predicts one keyframe kind once with the scene's own instruction and once with every other
skill text of the benchmark's tasks, worded about the same target; per skill text the table gives the median
position error (cm) against the expert's label and the median distance (cm) from the prediction with the scene's
own text.

Usage: python benchmarks/skill_text_probe.py --run models/abm_clip.pt --task place_wine --kind move
           [--episodes 5] [--split seen] [--resolution 128] [--grounder oracle] [--skill-tasks ...]
           [--out probe.json]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.cli import configure_logging
from abm.evaluation.diagnose.skill_text import SkillTextProbe
from abm.experiments.spec import load_spec
from abm.grounding.config import GROUNDERS


def main() -> None:
    paper_tasks = load_spec("paper_tables", check_tasks=False).data.tasks  # the paper's 8 tasks
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", required=True, type=Path, help="a mask variant's run folder, checkpoint or zoo file")
    p.add_argument("--task", required=True)
    p.add_argument("--kind", default="move", help="the expert keyframe kind to probe (default move)")
    p.add_argument("--split", default="seen")
    p.add_argument("--episodes", type=int, default=5)
    p.add_argument("--resolution", type=int, default=128, help="camera pixels (as in training)")
    p.add_argument("--grounder", choices=GROUNDERS.names(), default=None,
                   help="override the checkpoint's grounder (oracle: the simulator's mask)")
    p.add_argument("--skill-tasks", nargs="+", default=list(paper_tasks),
                   help="the tasks whose skill texts are tried (default: the paper's 8)")
    p.add_argument("--out", type=Path, default=None, help="write the rows as JSON")
    args = p.parse_args()
    configure_logging()
    SkillTextProbe(model=args.run, task=args.task, skill_tasks=tuple(args.skill_tasks), out=args.out,
                   keyframe=args.kind, split=args.split, episodes=args.episodes, resolution=args.resolution,
                   grounder=args.grounder).run()
    if args.out is not None:
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
