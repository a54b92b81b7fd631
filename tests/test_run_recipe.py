"""RUN/recipe.yaml holds what a run trains, not how the run was controlled (issue 40, item 8)."""

from __future__ import annotations

from pathlib import Path

from abm.train.config import RUN_CONTROL, TrainConfig


def test_the_recipe_leaves_the_run_controls_out():
    cfg = TrainConfig(out=Path("runs/x"), steps=10, resume=True, accept_changed_config=True, overwrite=True,
                      progress=False, verify=False, cache_dir=Path("c"), log_every=5, keep_checkpoints=1, workers=2,
                      lr=0.002, grounder={"kind": "clip", "model": "m"})
    recipe = cfg.to_recipe()
    assert not set(RUN_CONTROL) & set(recipe), sorted(set(RUN_CONTROL) & set(recipe))
    assert recipe["lr"] == 0.002 and recipe["steps"] == 10 and recipe["grounder"] == "clip"
    assert recipe["clip_model"] == "m"
