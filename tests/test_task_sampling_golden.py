"""Saved-output test of every task's scene sampler: seeds map to the same scenes forever.

Demonstrations, evaluation episodes and published results are identified by ``(task, split, seed)``;
a refactor of the task classes must not move a single object. The instructions, targets, role
indices and every object's name and pose for seeds 0-7 of every task and split are compared with
``tests/data/golden_task_samples.json``. An intended change regenerates it with
``python tests/test_task_sampling_golden.py --update`` and says why in the commit.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from abm.sim.splits import load_splits
from abm.sim.tasks import TASKS, get_task

GOLDEN = Path(__file__).parent / "data" / "golden_task_samples.json"
SEEDS = range(8)


def _samples() -> dict[str, dict]:
    splits = load_splits()
    out = {}
    for name in sorted(TASKS):
        task = get_task(name)
        for split in sorted(splits.tasks.get(name, {})):
            for seed in SEEDS:
                inst = task.sample(seed, split)
                out[f"{name}/{split}/{seed}"] = {
                    "instruction": inst.instruction, "variation": inst.variation,
                    "target_names": list(inst.target_names), "info": inst.info, "scene_info": inst.scene.info,
                    "objects": [[o.name, o.x, o.y, o.yaw, o.z] for o in inst.scene.objects],
                }
    return out


def test_every_seed_gives_the_saved_scene() -> None:
    stored = json.loads(GOLDEN.read_text())
    got = json.loads(json.dumps(_samples()))  # same JSON normalisation as the stored file
    assert sorted(got) == sorted(stored)
    for key, want in stored.items():
        have = got[key]
        for field in ("instruction", "variation", "target_names", "info", "scene_info"):
            assert have[field] == want[field], (key, field)
        assert [o[0] for o in have["objects"]] == [o[0] for o in want["objects"]], key
        for a, b in zip(have["objects"], want["objects"], strict=True):
            np.testing.assert_allclose([v if v is not None else np.nan for v in a[1:]],
                                       [v if v is not None else np.nan for v in b[1:]], atol=1e-12, err_msg=key)


if __name__ == "__main__":
    if "--update" not in sys.argv:
        sys.exit("usage: python tests/test_task_sampling_golden.py --update   (rewrites the saved samples)")
    GOLDEN.write_text(json.dumps(_samples(), indent=1, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN} ({GOLDEN.stat().st_size / 1024:.0f} KiB)")
