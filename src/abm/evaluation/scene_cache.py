"""The scenes an evaluation process keeps between rollouts, so several models rolled out on one scene build it once.

Building an episode's scene costs ~0.65 CPU s of a ~3-4 s rollout at 128² on a 2-core Xeon: compiling the MuJoCo
model (~0.2 s) and uploading its meshes and textures to the renderer (``mujoco.MjrContext``, ~0.45 s; the objects'
textures are up to 4096² texels). When the same scene (task, split, seed) is rolled out again in the process, for
another model of the same evaluation, :func:`kept_scene` hands the kept environment's model and renderer to the new
one (:class:`abm.sim.simulation.Simulation`'s ``reuse``): the simulator's state, the arm's controller and its IK are
made anew, so every rollout is the one a fresh build gives (``tests/test_scene_cache.py`` compares the outcomes).
The evaluation orders a multi-model run's rollouts scene by scene (:func:`abm.evaluation.runner.evaluate`).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from abm.sim.env import TaskEnv

KEEP = 1
"""Scenes kept per process (the renderer of a scene holds its textures: ~0.1 GB for the catalog's objects). One:
an evaluation rolls out every model of a scene one after another, with or without segmentation (oracle and
CLIP-grounded models) from the same build."""

SceneKey = tuple[str, str, int, int, int, str]
_KEPT: OrderedDict[SceneKey, TaskEnv] = OrderedDict()


@contextmanager
def kept_scene(task: str, split: str, seed: int, resolution: int, max_steps: int,
               splits_path: str | Path | None = None, segmentation: bool = True) -> Iterator[TaskEnv]:
    """``make_env(...)`` (see :class:`abm.sim.env.TaskEnv` for the arguments) that takes over the model and
    renderer of the same scene's environment if the process kept one, and is kept itself when the block ends
    (the oldest kept scene beyond :data:`KEEP` is closed). An exception in the block closes it instead."""
    from abm.sim.env import make_env  # mujoco (optional `sim` extra)

    key: SceneKey = (task, split, int(seed), int(resolution), int(max_steps), str(splits_path or ""))
    env = make_env(task, split, seed, resolution, max_steps=max_steps, splits_path=splits_path,
                   segmentation=segmentation, reuse=_KEPT.pop(key, None))
    try:
        yield env
    except BaseException:
        env.close()
        raise
    _KEPT[key] = env
    while len(_KEPT) > KEEP:
        _KEPT.popitem(last=False)[1].close()


def forget_scenes() -> None:
    """Close every kept scene (an evaluation in the calling process ends with this: no GL resources stay)."""
    while _KEPT:
        _KEPT.popitem()[1].close()


def kept_count() -> int:
    """How many scenes the process keeps now."""
    return len(_KEPT)
