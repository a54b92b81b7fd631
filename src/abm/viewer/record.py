"""What the viewer shows, as plain arrays: built from an episode or a rollout, independent of the browser.

A :class:`ViewerRecord` holds, for each keyframe step, the fused point cloud with its colours and its
Object Mask Field scores, the target's points, the five virtual views (rendered colour with the mask
tinted and the predicted translation heatmap on top) and the expert's and the predicted keyframes.
:mod:`abm.viewer.server` draws it with viser; tests check it without a browser.

Three sources:

* :func:`record_from_episode` with a grounder only: grounding as the policy would see it, no predictions;
* :func:`record_from_episode` with a policy: what the policy saw and predicted at each demonstration step;
* :func:`record_rollout`: the policy rolled out in the simulator (``abm eval``'s scenes), step by step.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from abm.configuration import CAMERA_RESOLUTION, MAX_KEYFRAMES
from abm.errors import ConfigError
from abm.geometry import Workspace
from abm.grounding.config import GrounderConfig, build_grounder
from abm.grounding.grounders import Grounder
from abm.grounding.visualize import overlay_views
from abm.language.roles import split_instruction
from abm.policy.keyframe_policy import PolicyExplanation, explain_grounding
from abm.render import OrthographicRenderer
from abm.render.orthographic import VIEW_AXES
from abm.types import Episode, KeyframeAction, Observation

EXPERT_COLOR = (40, 170, 60)  # green
PREDICTED_COLOR = (240, 120, 0)  # orange


@dataclass
class ViewerStep:
    """One keyframe step (``N`` points, ``V`` views of ``R x R`` pixels).

    Attributes:
        index: step number within the episode.
        points: ``(N, 3)`` float32 world metres.
        colors: ``(N, 3)`` uint8 RGB.
        scores: ``(N,)`` float32 Object Mask Field scores in ``[0, 1]`` (``None`` without a grounder).
        target: ``(N,)`` bool, the thresholded mask (the points the policy attends to).
        views: ``V`` images ``(R, R, 3)`` uint8: rendered colour, mask tint, heatmap overlay.
        expert: the demonstration's keyframe from this step (``None`` for rollouts).
        predicted: the policy's keyframe (``None`` without a policy).
        gripper_pose: ``(4, 4)`` the gripper's pose when the step was observed.
    """

    index: int
    points: np.ndarray
    colors: np.ndarray
    scores: np.ndarray | None
    target: np.ndarray | None
    views: list[np.ndarray]
    expert: KeyframeAction | None
    predicted: KeyframeAction | None
    gripper_pose: np.ndarray


@dataclass
class ViewerRecord:
    """Everything :func:`abm.viewer.server.serve` draws.

    Attributes:
        title: one line saying where the record comes from.
        instruction: the episode's instruction.
        target_name: the object the instruction names (``None`` if unknown).
        workspace: the policy's workspace cube (drawn as a wire box; the virtual cameras sit on its faces).
        view_names: names of the virtual views, in ``ViewerStep.views`` order.
        steps: the keyframe steps.
        success: whether the episode succeeded (``None`` if unknown).
    """

    title: str
    instruction: str
    target_name: str | None
    workspace: Workspace
    view_names: list[str]
    steps: list[ViewerStep] = field(default_factory=list)
    success: bool | None = None


def view_camera_pose(workspace: Workspace, view: str, distance: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
    """Where a virtual camera is drawn: ``(position (3,), wxyz (4,))``, looking at the cube's centre.

    The orthographic view looks along its forward axis (see :data:`abm.render.orthographic.VIEW_AXES`);
    the camera is placed ``distance`` metres outside the cube face it looks through, with OpenCV axes
    (x = image right, y = image down, z = forward), which is viser's camera convention.
    """
    right, down, forward = (np.asarray(a, np.float64) for a in VIEW_AXES[view])
    rotation = np.stack([right, down, forward], axis=1)  # columns: the camera's axes in the world
    position = np.asarray(workspace.center, np.float64) - forward * (workspace.half + distance)
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return position, np.array([w, x, y, z])


def _step_from_sample(index: int, sample: Mapping[str, Any], views: list[np.ndarray], obs: Observation,
                      expert: KeyframeAction | None, predicted: KeyframeAction | None) -> ViewerStep:
    def arr(key: str) -> np.ndarray | None:
        value = sample.get(key)
        return None if value is None else np.asarray(value.numpy() if torch.is_tensor(value) else value)

    heat, mask, points, colors = arr("point_heatmap"), arr("point_mask"), arr("points"), arr("colors")
    assert points is not None and colors is not None  # every sample has them (abm.samples)
    return ViewerStep(index=index, points=points.astype(np.float32),
                      colors=(np.clip(colors, 0, 1) * 255).astype(np.uint8),
                      scores=None if heat is None else heat.astype(np.float32),
                      target=None if mask is None else mask > 0.5, views=views, expert=expert, predicted=predicted,
                      gripper_pose=np.asarray(obs.gripper_pose, np.float64))


def _target_name(episode: Episode) -> str | None:
    try:
        return split_instruction(episode.instruction, episode.object_names)[0]
    except ValueError:
        return None


def _select(steps: Sequence[int] | None, count: int) -> list[int]:
    chosen = list(range(count)) if steps is None else list(steps)
    bad = [k for k in chosen if not 0 <= k < count]
    if bad:
        raise ConfigError(f"step {bad[0]} does not exist: the episode has steps 0..{count - 1}")
    return chosen


def record_from_episode(
    episode: Episode,
    policy: Any | None = None,
    grounder: Grounder | GrounderConfig | Mapping[str, Any] | None = None,
    workspace: Workspace | None = None,
    view_resolution: int = 128,
    steps: Sequence[int] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ViewerRecord:
    """The viewer record of a demonstration (or any stored episode).

    Args:
        episode: the episode; its actions are shown as the expert's keyframes.
        policy: a :class:`abm.policy.KeyframePolicy`; when given, each step shows what it saw
            (:meth:`~abm.policy.KeyframePolicy.explain`) and predicted, in its workspace and views.
        grounder: without a policy, the grounder configuration (its dict form) or object that computes the mask field
            (default the oracle: the simulator's segmentation of the named object).
        workspace: without a policy, the crop cube (default :class:`Workspace`'s default).
        view_resolution: without a policy, the side of the rendered virtual views.
        steps: the step indices to include (default all).
        progress: called with ``(done, total)`` after each step.
    """
    chosen = _select(steps, len(episode.steps))
    if policy is not None:
        names = list(policy.renderer.views)
        record = ViewerRecord(f"{episode.task}/{episode.split} seed {episode.seed}, policy {policy.config.variant}",
                            episode.instruction, None, policy.workspace, names, success=episode.success)
    else:
        ws = workspace or Workspace()
        renderer = OrthographicRenderer(ws, view_resolution)
        names = list(renderer.views)
        g = grounder if isinstance(grounder, Grounder) else build_grounder(grounder)  # a config, its dict or None
        record = ViewerRecord(f"{episode.task}/{episode.split} seed {episode.seed}, grounding only",
                            episode.instruction, None, ws, names, success=episode.success)
    for done, k in enumerate(chosen, 1):
        obs, expert = episode.steps[k]
        if policy is not None:
            seen = policy.explain(obs, episode.instruction, episode.object_names)
            views = overlay_views(seen.view_rgb, seen.view_target, seen.heatmaps, seen.view_mask)
            record.steps.append(_step_from_sample(k, seen.sample, views, obs, expert, seen.action))
        else:  # what a mask policy with these views would see (the policy module's one way of computing it)
            seen = explain_grounding(obs, episode.instruction, renderer, g, episode.object_names)
            record.target_name = seen.target
            views = overlay_views(seen.view_rgb, seen.view_target)
            record.steps.append(_step_from_sample(k, seen.sample, views, obs, expert, None))
        if progress is not None:
            progress(done, len(chosen))
    if policy is not None and record.target_name is None:
        record.target_name = _target_name(episode)
    return record


def record_rollout(policy: Any, task: str, split: str = "seen", seed: int = 1_000_000,
                  resolution: int = CAMERA_RESOLUTION, max_steps: int = MAX_KEYFRAMES) -> ViewerRecord:
    """Roll ``policy`` out on one seeded ABM-Bench scene (as ``abm eval`` does) and keep every step's view.

    ``seed`` is the scene seed (``abm eval`` writes it into its outcome log); the scene, the instruction
    and the objects are the same as in that evaluation episode.
    """
    from abm.sim.env import make_env, run_policy  # mujoco (optional `sim` extra): episodes view without it

    explained: list[PolicyExplanation] = []
    with make_env(task, split, seed, resolution, max_steps=max_steps) as env:
        policy.reset()

        def act(obs: Observation) -> KeyframeAction:
            explained.append(policy.explain(obs, env.instruction, env.object_names))
            return explained[-1].action

        episode = run_policy(env, act)
    record = ViewerRecord(f"rollout of {policy.config.variant} on {task}/{split} seed {seed}: "
                        f"{'success' if episode.success else 'failure'}", episode.instruction, None,
                        policy.workspace, list(policy.renderer.views), success=episode.success)
    for k, ((obs, _), seen) in enumerate(zip(episode.steps, explained, strict=True)):
        views = overlay_views(seen.view_rgb, seen.view_target, seen.heatmaps, seen.view_mask)
        record.steps.append(_step_from_sample(k, seen.sample, views, obs, None, seen.action))
    record.target_name = _target_name(episode)
    return record
