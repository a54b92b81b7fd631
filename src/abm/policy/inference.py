"""Inference wrapper: one observation + instruction -> the next keyframe action.

``Policy.act`` does the whole per-step pipeline of the method: camera fusion into a workspace-cropped
point cloud, instruction decomposition and grounding of the target (mask variants) or CLIP point
features (``ifd``), re-rendering into the virtual views, the transformer forward pass (bf16 autocast
on CUDA) and decoding of the heatmaps and logits into a :class:`~abm.types.KeyframeAction`.

Example::

    policy = Policy.load("runs/abm", device="cuda")
    action = policy.act(observation, "put the ketchup in the plate", object_names=episode.object_names)
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from abm.geometry import Workspace, fuse_cameras
from abm.policy.action_coding import proprioception
from abm.policy.conditioning import ground_points, language_text, make_grounder_from_spec, split_instruction
from abm.policy.config import PolicyConfig
from abm.policy.heads import decode_output
from abm.policy.language import LanguageEncoder, make_language_encoder
from abm.policy.mvt import MultiViewTransformer, PolicyOutput
from abm.render import OrthographicRenderer
from abm.types import KeyframeAction, Observation


class Policy:
    """A trained policy ready to act.

    Args:
        model: the network (moved to ``device``, put in eval mode).
        language: encoder of the language goal (texts are encoded once and cached).
        grounder: grounder spec (``{"kind": "oracle"}``, ``{"kind": "clip", ...}``) or a grounder object
            with ``ground(observation, cloud, target, object_names)``.
        camera_names: cameras to fuse (default all of the observation's).
        device: torch device.
    """

    def __init__(
        self,
        model: MultiViewTransformer,
        language: LanguageEncoder,
        grounder: Mapping[str, Any] | Any | None = None,
        camera_names: Sequence[str] | None = None,
        device: str | torch.device = "cpu",
    ) -> None:
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.config: PolicyConfig = model.config
        self.spec = self.config.spec
        self.language = language
        self._grounder_spec = dict(grounder) if isinstance(grounder, Mapping) else None
        self._grounder = None if isinstance(grounder, Mapping) or grounder is None else grounder
        if grounder is None:
            self._grounder_spec = {"kind": "oracle"}
        self.camera_names = list(camera_names) if camera_names else None
        self.workspace = Workspace(self.config.workspace_center, self.config.workspace_size)
        self.renderer = OrthographicRenderer(self.workspace, self.config.resolution, self.config.views,
                                             device=self.device)
        self._lang_cache: dict[str, torch.Tensor] = {}
        self.last_timings: dict[str, float] = {}
        self.checkpoint_path: str | None = None

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(
        cls,
        run_or_ckpt: str | Path,
        device: str | torch.device = "cpu",
        grounder: Mapping[str, Any] | Any | None = None,
        expect_variant: str | None = None,
    ) -> Policy:
        """Load a checkpoint file or the latest checkpoint of a run folder.

        Args:
            run_or_ckpt: ``RUN/`` or ``RUN/checkpoints/step_XXXXXXXX.pt``.
            device: where to run.
            grounder: override the grounder stored in the checkpoint (spec or object); a spec of the
                same kind only overrides the options it names.
            expect_variant: if given, a checkpoint of another variant raises ``ValueError``.
        """
        from abm.train.checkpoint import load_checkpoint

        ckpt = load_checkpoint(run_or_ckpt, map_location="cpu")
        config = PolicyConfig.from_dict(ckpt["policy_config"])
        if expect_variant is not None and config.variant != expect_variant:
            raise ValueError(
                f"checkpoint {ckpt['path']} is a {config.variant!r} policy, expected {expect_variant!r}"
            )
        model = MultiViewTransformer(config)
        model.load_state_dict(ckpt["model"])
        stored = ckpt.get("grounder")
        if isinstance(grounder, Mapping) and isinstance(stored, Mapping) and grounder.get("kind") == stored.get("kind"):
            grounder = {**stored, **grounder}  # same grounder: keep the trained options (e.g. the CLIP model)
        policy = cls(model, make_language_encoder(ckpt["language"]), grounder or stored,
                     ckpt.get("camera_names"), device)
        policy.checkpoint_path = ckpt["path"]
        return policy

    # ------------------------------------------------------------------ pipeline
    @property
    def grounder(self) -> Any:
        if self._grounder is None:
            self._grounder = make_grounder_from_spec(self._grounder_spec or {"kind": "oracle"})
        return self._grounder

    def _lang(self, text: str) -> torch.Tensor:
        if text not in self._lang_cache:
            self._lang_cache[text] = self.language.encode([text])[0]
        return self._lang_cache[text]

    def prepare(
        self,
        observation: Observation,
        instruction: str,
        object_names: Mapping[int, str] | None = None,
    ) -> dict[str, torch.Tensor]:
        """Model inputs (batch of 1, on the policy's device) for one observation."""
        from abm.data.keyframes import render_inputs

        t0 = time.perf_counter()
        cloud = fuse_cameras(observation, self.workspace, self.camera_names)
        target, skill = None, None
        if self.spec.uses_mask or self.spec.language == "skill":
            target, skill = split_instruction(instruction, object_names)
        t1 = time.perf_counter()
        point_mask, feats = None, None
        if self.spec.uses_mask:
            if self._grounder_spec and self._grounder_spec.get("kind") == "oracle" and object_names is None:
                raise ValueError("the oracle grounder needs object_names (segmentation id -> name)")
            point_mask = ground_points(self.grounder, observation, cloud, target, object_names or {})
        if self.spec.clip_features:
            feats = np.asarray(self.grounder.point_features(observation, cloud), np.float32)
        t2 = time.perf_counter()
        sample = render_inputs(self.renderer, self.config, cloud.xyz, cloud.rgb, point_mask, feats)
        sample["proprio"] = torch.from_numpy(
            proprioception(observation.gripper_open, observation.gripper_pose[:3, 3], self.workspace))
        sample["lang"] = self._lang(language_text(self.spec, instruction, skill))
        t3 = time.perf_counter()
        self.last_timings = {"fuse_s": t1 - t0, "ground_s": t2 - t1, "render_s": t3 - t2}
        return {k: v.unsqueeze(0).to(self.device) for k, v in sample.items()}

    @torch.no_grad()
    def forward(self, inputs: Mapping[str, torch.Tensor]) -> PolicyOutput:
        """Run the network on prepared inputs (bf16 autocast on CUDA)."""
        with torch.autocast(device_type=self.device.type, dtype=torch.bfloat16,
                            enabled=self.device.type == "cuda"):
            return self.model(inputs["images"], inputs["proprio"], inputs["lang"], mask=inputs.get("mask"),
                              ifd_features=inputs.get("ifd_features"), ifd_index=inputs.get("ifd_index"))

    def act(
        self,
        observation: Observation,
        instruction: str,
        object_names: Mapping[int, str] | None = None,
    ) -> KeyframeAction:
        """The next keyframe for ``observation`` under ``instruction``.

        Args:
            observation: the current cameras and gripper state.
            instruction: the full English instruction.
            object_names: segmentation id -> object name (needed by the oracle grounder, and used to
                find the target in the instruction when no decomposition template matches).

        Timings of the last call (seconds per stage) are in :attr:`last_timings`.
        """
        inputs = self.prepare(observation, instruction, object_names)
        t0 = time.perf_counter()
        out = self.forward(inputs)
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        t1 = time.perf_counter()
        action = decode_output(out, self.renderer)[0]
        self.last_timings.update(model_s=t1 - t0, decode_s=time.perf_counter() - t1)
        return action
