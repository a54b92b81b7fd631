"""Regenerate the version-1 checkpoints (grounder stored as a plain dict spec) of test_old_checkpoints.py.

These files were written by abm at commit 5b86c96, before the typed grounder configurations
(abm.grounding.config) existed; the test checks today's code still loads them. Do not regenerate them with
newer code (that would defeat the test); run this only at that commit::

    PYTHONPATH=src python tests/data/checkpoints_v1/generate.py
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from abm.policy import KeyframePolicy
from abm.train import TrainConfig, train
from abm.train.synthetic import synthetic_episodes

HERE = Path(__file__).parent
TINY = {"resolution": 16, "width": 16, "heads": 2, "layers_within": 1, "layers_joint": 1, "stem_channels": 4,
        "decoder_channels": 4, "lang_dim": 16}
RUNS = {
    "oracle": dict(grounder="oracle"),
    "clip": dict(grounder="clip", grounder_options={"model": "tiny", "device": "cpu", "mode": "field",
                                                    "threshold": 0.3}, language="hash"),
}
# a checkpoint saved with an evaluation grounder (old shortcut keys: scoring, normalization)
EXPORTS = {"tracking": ("oracle", {"kind": "tracking", "inner": {"kind": "clip", "model": "tiny", "scoring": "combined",
                                                                  "normalization": "minmax"}, "radius": 0.02})}


def main() -> None:
    episodes = synthetic_episodes(1, camera_resolution=32)
    obs, _ = episodes[0].steps[0]
    expected = {}
    for name, kw in RUNS.items():
        run = HERE / f"run_{name}"
        shutil.rmtree(run, ignore_errors=True)
        cfg = TrainConfig(method="abm", preset="small", out=run, steps=1, batch=1, checkpoint_every=1, log_every=1,
                          policy_overrides=dict(TINY), progress=False, warmup=1, cache_dir=HERE / "tmp_cache", **kw)
        train(cfg, episodes)
        shutil.rmtree(HERE / "tmp_cache", ignore_errors=True)
        for extra in ("log.csv", "summary.json", "tb"):
            p = run / extra
            shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
    for name, (source, grounder) in EXPORTS.items():
        policy = KeyframePolicy.from_checkpoint(HERE / f"run_{source}", grounder=grounder)
        policy.save(HERE / f"{name}.pt")
    for name, path in [("oracle", HERE / "run_oracle"), ("clip", HERE / "run_clip"),
                       ("tracking", HERE / "tracking.pt")]:
        policy = KeyframePolicy.from_checkpoint(path)
        seen = policy.explain(obs, episodes[0].instruction, episodes[0].object_names)
        expected[name] = {"grounder": policy.grounder_spec, "position": seen.action.position.tolist(),
                          "quaternion": seen.action.quaternion.tolist(),
                          "gripper_open": bool(seen.action.gripper_open),
                          "heatmap_sum": float(np.sum(seen.heatmaps * np.arange(seen.heatmaps.size).reshape(
                              seen.heatmaps.shape) / seen.heatmaps.size)),
                          "point_mask_sum": float(seen.sample["point_mask"].sum())}
    (HERE / "expected.json").write_text(json.dumps(expected, indent=1) + "\n")


if __name__ == "__main__":
    main()
