"""benchmarks/rotation_fit.py: per-axis rotation cross-entropy on a run's own training keyframes."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
import torch

from abm.data.keyframes import KeyframeDataset
from abm.policy import KeyframePolicy
from abm.train.synthetic import synthetic_episode

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
rotation_fit = pytest.importorskip("rotation_fit")


def test_a_head_that_guesses_uniformly_scores_ln_bins_on_every_axis_and_a_label_copy_scores_zero(
        shared_tiny_run: Path) -> None:
    policy = KeyframePolicy.from_checkpoint(shared_tiny_run).eval()
    dataset = KeyframeDataset([synthetic_episode(s, 32) for s in range(2)], policy.workspace, policy.grounder_config,
                              **policy.sample_options(), augment=False, seed=0)
    last = policy.model.global_head[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    bins = policy.config.rotation_bins
    assert rotation_fit.axis_cross_entropy(policy, dataset) == pytest.approx([math.log(bins)] * 3, abs=1e-5)
    # every label of the synthetic episodes has the same roll and pitch: logits on those bins fit them exactly
    first = policy.targets(rotation_fit.collate([dataset[0]]))["rotation_bins"][0]
    with torch.no_grad():
        for axis in (0, 1):
            last.bias[axis * bins + int(first[axis])] = 100.0
    ce = rotation_fit.axis_cross_entropy(policy, dataset, batch=3)
    assert ce[0] == pytest.approx(0.0, abs=1e-4) and ce[1] == pytest.approx(0.0, abs=1e-4)
    assert ce[2] == pytest.approx(math.log(bins), abs=1e-5)
