"""``KeyframePolicy.explain`` / ``explain_grounding`` are the one place that computes what a policy saw; the
pictures drawn from them equal those the viewer, the quickstart report and the robot log drew before they
used it (each re-rendered the views itself)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from abm.grounding.config import OracleGrounderConfig, build_grounder
from abm.grounding.visualize import overlay_views
from abm.policy import GroundingExplanation, KeyframePolicy, PolicyExplanation, explain_grounding
from abm.render import OrthographicRenderer
from abm.samples import collate
from abm.train.synthetic import synthetic_episodes
from abm.viewer.record import record_from_episode

RUN = Path(__file__).parent / "data" / "checkpoints_v1" / "run_oracle"


@pytest.fixture(scope="module")
def episode():
    return synthetic_episodes(1, camera_resolution=32)[0]


def test_explain_returns_the_network_input_and_the_scene(episode) -> None:
    policy = KeyframePolicy.from_checkpoint(RUN)
    obs, _ = episode.steps[0]
    seen = policy.explain(obs, episode.instruction, episode.object_names)
    assert isinstance(seen, PolicyExplanation) and isinstance(seen, GroundingExplanation)
    # the old route of the quickstart figure and the robot log: observe + model_inputs
    inputs = policy.model_inputs(collate([policy.observe(obs, episode.instruction, episode.object_names)]))
    np.testing.assert_array_equal(seen.view_images, inputs["images"][0].numpy())
    np.testing.assert_array_equal(seen.view_mask, inputs["mask"][0, :, 0].numpy())
    v, r = policy.renderer.num_views, policy.renderer.resolution
    assert seen.view_images.shape == (v, 10, r, r) and seen.view_target.shape == (v, r, r)
    assert seen.view_target.dtype == bool and seen.view_target.any()
    assert seen.target == episode.target_names[0]
    assert seen.sample["points"].shape[0] == seen.sample["point_mask"].shape[0]


def test_explain_scene_equals_the_viewers_former_rendering(episode) -> None:
    obs, _ = episode.steps[1]
    renderer = OrthographicRenderer(policy_ws := KeyframePolicy.from_checkpoint(RUN).workspace, 40)
    grounder = build_grounder(OracleGrounderConfig())
    seen = explain_grounding(obs, episode.instruction, renderer, grounder, episode.object_names)
    # what abm/viewer/record.py computed itself before
    from abm.grounding.conditioning import condition_cloud

    cond = condition_cloud(obs, episode.instruction, policy_ws, grounder=grounder, object_names=episode.object_names,
                           mask=True)
    rendered = renderer.render(torch.from_numpy(cond.cloud.xyz)[None], torch.from_numpy(cond.cloud.rgb)[None],
                               extra=torch.from_numpy(cond.point_mask.mask[:, None])[None])
    old = overlay_views(rendered.rgb[0].permute(0, 2, 3, 1).numpy(), rendered.extra[0, :, 0].numpy())
    new = overlay_views(seen.view_rgb, seen.view_target)
    for a, b in zip(old, new, strict=True):
        np.testing.assert_array_equal(a, b)
    assert seen.target == cond.target
    np.testing.assert_array_equal(seen.sample["points"].numpy(), cond.cloud.xyz)
    np.testing.assert_array_equal(seen.sample["point_heatmap"].numpy(), cond.point_mask.heatmap)


def test_viewer_scene_draws_from_explain(episode) -> None:
    policy = KeyframePolicy.from_checkpoint(RUN)
    scene = record_from_episode(episode, policy, steps=[0])
    obs, _ = episode.steps[0]
    seen = policy.explain(obs, episode.instruction, episode.object_names)
    want = overlay_views(seen.view_rgb, seen.view_target, seen.heatmaps, seen.view_mask)
    for a, b in zip(scene.steps[0].views, want, strict=True):
        np.testing.assert_array_equal(a, b)
