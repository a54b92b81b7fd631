"""How well a policy fits the yaw (and roll, pitch) labels of its own training keyframes, per keyframe kind.

For every keyframe of a dataset the policy predicts teacher-forced, exactly as in training
(:meth:`abm.policy.KeyframePolicy.teacher_forced`: the rotation head pools at the label's heatmap, a two-stage
policy zooms on the label), and the cross-entropy of each Euler axis's bins against the label is averaged per
group of keyframes (task and keyframe kind, and over all keyframes).

Two reference lines make a yaw number readable at a glance:

* **chance** -- a uniform guess over the bins the label can take given the keyframe's symmetry: the canonical
  label of a ``k``-fold symmetric grasp lies in a ``360 / k`` degree range, so ``ln(bins / k)`` (ln 36 = 3.58 for
  the two-fold gripper with 72 bins, ln 18 = 2.89 for a square object); a round object's label is fixed
  (chance 0); a grasp with no symmetry can take every bin (ln 72).
* **prior** -- what a model that knows only the task and the keyframe kind scores: the entropy of the group's
  empirical label distribution. A head below it reads something off the scene; a head at it does not.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from abm.data.keyframes import KeyframeDataset
from abm.geometry.rotations import ROUND_SYMMETRY
from abm.policy import KeyframePolicy
from abm.samples import collate

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class FitRow:
    """Fit of one group of keyframes.

    Attributes:
        task: the task, or ``"all"``.
        keyframe: the keyframe kind (``approach``, ``grasp``, ...), or ``"all"``.
        keyframes: keyframes in the group.
        cross_entropy: mean cross-entropy (nats) of the x, y, z bins.
        yaw_chance: the yaw's chance line (nats): ``ln`` of the bins the canonical label can take, averaged
            over the group's keyframes (their symmetries may differ).
        yaw_prior: entropy (nats) of the group's yaw labels: the score of a model that knows only the group.
    """

    task: str
    keyframe: str
    keyframes: int
    cross_entropy: tuple[float, float, float]
    yaw_chance: float
    yaw_prior: float

    @property
    def yaw(self) -> float:
        return self.cross_entropy[2]


def yaw_chance(symmetry: int, bins: int) -> float:
    """Cross-entropy (nats) of a uniform guess over the yaw bins a canonical label of this symmetry can take."""
    if symmetry == ROUND_SYMMETRY:
        return 0.0
    return math.log(max(bins // max(symmetry, 1), 1))


def _entropy(labels: list[int]) -> float:
    counts = np.array(list(Counter(labels).values()), dtype=np.float64)
    p = counts / counts.sum()
    return float(-(p * np.log(p)).sum())


def rotation_fit(policy: KeyframePolicy, dataset: KeyframeDataset, batch: int = 16) -> list[FitRow]:
    """Per-axis cross-entropy of ``policy`` on every keyframe of ``dataset``, grouped by task and keyframe kind.

    Returns one row per (task, kind) in dataset order, one per kind over all tasks (task ``"all"``) and one over
    everything (``"all"``, ``"all"``).
    """
    was_training = policy.training
    policy.eval()
    bins = policy.config.rotation_bins
    losses: list[np.ndarray] = []
    labels: list[int] = []
    groups: list[tuple[str, str, int]] = []  # (task, kind, symmetry) per keyframe
    try:
        with torch.no_grad():
            for start in range(0, len(dataset), batch):
                items = range(start, min(len(dataset), start + batch))
                samples = collate([dataset[j] for j in items])
                out, target = policy.teacher_forced(samples)
                rot = target["rotation_bins"]
                ce = torch.stack([F.cross_entropy(out.rotation[:, a].float(), rot[:, a], reduction="none")
                                  for a in range(3)], -1)
                losses.extend(ce.cpu().numpy())
                labels.extend(int(v) for v in rot[:, 2].cpu())
                for j in items:
                    episode, step = dataset.items[j]
                    action = dataset.source.load_step(episode, step)[1]
                    kind = action.kind or "unlabelled"
                    groups.append((dataset.source.meta[episode].task, kind, int(action.symmetry)))
    finally:
        policy.train(was_training)
    members: dict[tuple[str, str], list[int]] = defaultdict(list)
    for i, (task, kind, _) in enumerate(groups):
        for key in ((task, kind), ("all", kind), ("all", "all")):
            members[key].append(i)
    rows = []
    for (task, kind), idx in members.items():
        ce = np.mean([losses[i] for i in idx], axis=0)
        chance = float(np.mean([yaw_chance(groups[i][2], bins) for i in idx]))
        rows.append(FitRow(task, kind, len(idx), (float(ce[0]), float(ce[1]), float(ce[2])), chance,
                           _entropy([labels[i] for i in idx])))
    order = {"all": 1}
    return sorted(rows, key=lambda r: (order.get(r.task, 0), r.task == "all" and r.keyframe == "all"))
