"""abm.evaluation.rotation_fit: per-axis rotation cross-entropy on a run's own training keyframes, per keyframe
kind, with the chance line of each symmetry and the task-and-kind prior."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from abm.data.keyframes import KeyframeDataset
from abm.evaluation.rotation_fit import rotation_fit, yaw_chance
from abm.policy import KeyframePolicy
from abm.samples import collate
from abm.train.synthetic import synthetic_episode


def test_chance_lines_follow_the_symmetry() -> None:
    assert yaw_chance(2, 72) == pytest.approx(math.log(36))
    assert yaw_chance(4, 72) == pytest.approx(math.log(18))
    assert yaw_chance(1, 72) == pytest.approx(math.log(72))
    assert yaw_chance(0, 72) == 0.0  # round: the canonical label is fixed


def test_a_uniform_head_scores_ln_bins_and_a_label_copy_scores_zero_per_keyframe_kind(shared_tiny_run: Path) -> None:
    policy = KeyframePolicy.from_checkpoint(shared_tiny_run).eval()
    dataset = KeyframeDataset([synthetic_episode(s, 32) for s in range(2)], policy.workspace, policy.grounder_config,
                              **policy.sample_options(), augment=False, seed=0)
    last = policy.model.global_head[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    bins = policy.config.rotation_bins
    rows = rotation_fit(policy, dataset)
    kinds = {dataset.source.load_step(*dataset.items[i])[1].kind or "unlabelled" for i in range(len(dataset))}
    assert {r.keyframe for r in rows if r.task != "all"} == kinds
    overall = [r for r in rows if r.task == "all" and r.keyframe == "all"]
    assert len(overall) == 1 and overall[0].keyframes == len(dataset)
    for r in rows:
        assert r.cross_entropy == pytest.approx((math.log(bins),) * 3, abs=1e-5)
        assert 0.0 <= r.yaw_prior <= math.log(r.keyframes) + 1e-9
    # every label of the synthetic episodes has the same roll and pitch: logits on those bins fit them exactly
    first = policy.targets(collate([dataset[0]]))["rotation_bins"][0]
    with torch.no_grad():
        for axis in (0, 1):
            last.bias[axis * bins + int(first[axis])] = 100.0
    for r in rotation_fit(policy, dataset, batch=3):
        assert r.cross_entropy[0] == pytest.approx(0.0, abs=1e-4) and r.cross_entropy[1] == pytest.approx(0.0, abs=1e-4)
        assert r.yaw == pytest.approx(math.log(bins), abs=1e-5)
