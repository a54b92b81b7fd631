"""Tiny synthetic demonstrations for smoke tests, benchmarks and ``abm train --synthetic N``.

Each episode is the built-in block scene of :mod:`abm.render.synthetic` with the instruction "put the
<colour> block on the target" and two keyframes: grasp the target block from above (gripper closes),
then lift it 20 cm (gripper stays closed, collisions ignored). The target's position comes from its
segmented points, so actions are consistent with the images. No simulator is needed.
"""

from __future__ import annotations

import numpy as np

from abm.geometry import Workspace, euler_to_quat, fuse_cameras
from abm.render.synthetic import synthetic_scene
from abm.types import Episode, KeyframeAction, Observation


def synthetic_episode(seed: int, camera_resolution: int = 64) -> Episode:
    """One synthetic two-keyframe episode (deterministic in ``seed``)."""
    obs, names = synthetic_scene(seed=seed, resolution=camera_resolution)
    rng = np.random.default_rng(seed)
    target_id = int(rng.choice(sorted(names)))
    target = names[target_id]
    cloud = fuse_cameras(obs, Workspace())
    seg = cloud.gather({n: f.segmentation for n, f in obs.cameras.items()
                        if f.segmentation is not None})  # the synthetic scene's cameras all have one
    pts = cloud.xyz[seg == target_id]
    if len(pts) == 0:
        raise ValueError(f"synthetic scene {seed}: target {target!r} is not visible")
    top = np.array([pts[:, 0].mean(), pts[:, 1].mean(), pts[:, 2].max()])
    yaw = float(rng.choice([-90.0, -45.0, 0.0, 45.0, 90.0]))
    quat = euler_to_quat(np.array([180.0, 0.0, yaw]))
    grasp = KeyframeAction(top, quat, gripper_open=False, ignore_collision=False)
    lift = KeyframeAction(top + np.array([0.0, 0.0, 0.2]), quat, gripper_open=False, ignore_collision=True)
    pose1 = np.eye(4)
    pose1[:3, 3] = top
    obs2 = Observation(obs.cameras, gripper_open=0.0, gripper_pose=pose1, step=1)
    instruction = f"put the {target} on the target"
    return Episode(task="pick_block", variation=0, split="seen", instruction=instruction,
                   object_names=dict(names), target_names=[target], steps=[(obs, grasp), (obs2, lift)],
                   success=True, seed=seed)


def synthetic_episodes(count: int, camera_resolution: int = 64, seed: int = 0) -> list[Episode]:
    """``count`` synthetic episodes with seeds ``seed, seed + 1, ...``."""
    return [synthetic_episode(seed + i, camera_resolution) for i in range(count)]
