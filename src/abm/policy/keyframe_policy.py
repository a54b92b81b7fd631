"""The policy object: one ``nn.Module`` that owns the renderer, the conditioning, the language cache,
the action coding and the network, for training and for acting.

* :meth:`KeyframePolicy.compute_loss` (= ``forward``) takes a batch of policy-independent samples
  (:mod:`abm.samples`), renders them into the virtual views on the policy's device, builds the
  targets and returns ``(loss, metrics)``;
* :meth:`KeyframePolicy.predict` decodes a batch into keyframe actions;
* :meth:`KeyframePolicy.act` runs the whole per-step pipeline on one observation, and
  :meth:`KeyframePolicy.explain` also returns what it saw (:class:`PolicyExplanation`: the fused cloud,
  target mask, virtual views, network input and heatmaps) - the one place that computes it; viewers, reports
  and logs draw from it (and :func:`explain_grounding` for the same without a network);
* :meth:`KeyframePolicy.save` / :meth:`KeyframePolicy.from_checkpoint` write and read checkpoints.

Example::

    policy = KeyframePolicy.from_checkpoint("runs/abm", device="cuda")
    action = policy.act(observation, "put the ketchup in the plate", object_names=episode.object_names)

    policy = KeyframePolicy(PolicyConfig.from_preset("small", "abm"), {"kind": "hash", "dim": 512})
    loss, metrics = policy.compute_loss(batch)          # batch = abm.samples.collate([...])
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from abm.errors import CheckpointError, ConfigError
from abm.geometry import Workspace, quat_to_bins
from abm.grounding.conditioning import condition_cloud
from abm.grounding.config import (
    GrounderConfig,
    OracleGrounderConfig,
    as_grounder_config,
    build_grounder,
    grounder_config_from_dict,
    merge_grounder_configs,
)
from abm.policy.checkpoint import load_checkpoint, save_checkpoint
from abm.policy.config import PolicyConfig
from abm.policy.heads import decode_output, decode_translation, policy_loss, translation_targets
from abm.policy.language import LanguageEncoder
from abm.policy.language_config import LanguageConfig, build_language_encoder
from abm.policy.mvt import MultiViewTransformer, PolicyOutput
from abm.policy.variants import mask_channel
from abm.render import OrthographicRenderer
from abm.samples import Batch, Sample, cloud_sample, collate
from abm.types import KeyframeAction, Observation

if TYPE_CHECKING:
    from abm.grounding.grounders import Grounder

LOSS_TERMS = ("total", "translation", "rotation", "gripper", "collision", "zoom_translation")


@dataclass
class GroundingExplanation:
    """What a policy sees of one observation: the fused cloud, the target's mask over it and the ``V``
    virtual views (``H x W`` pixels each) it is rendered into. Positions are world coordinates in metres.

    Attributes:
        sample: the policy's input sample (:mod:`abm.samples`): ``points`` ``(N, 3)`` float32 m (the fused,
            workspace-cropped cloud), ``colors`` ``(N, 3)`` float32 in ``[0, 1]``, and for grounded scenes
            ``point_mask`` ``(N,)`` float32 in {0, 1} (the target) and ``point_heatmap`` ``(N,)`` float32 in
            ``[0, 1]`` (the grounder's score); CPU tensors.
        target: the grounded object's name (the active sub-goal's), ``None`` when the instruction is not split.
        view_names: names of the ``V`` views.
        view_rgb: ``(V, H, W, 3)`` float32 in ``[0, 1]``, the rendered colour of each view.
        view_occupied: ``(V, H, W)`` bool, where a point is visible.
        view_target: ``(V, H, W)`` bool, where the target's masked points are visible (``None`` without a mask).
    """

    sample: Sample
    target: str | None
    view_names: list[str]
    view_rgb: NDArray[np.float32]
    view_occupied: NDArray[np.bool_]
    view_target: NDArray[np.bool_] | None


@dataclass
class PolicyExplanation(GroundingExplanation):
    """One :meth:`KeyframePolicy.explain` step: :class:`GroundingExplanation` (``view_rgb`` is the colour the
    network saw) plus the network's input and output.

    Attributes:
        action: the predicted keyframe.
        view_images: ``(V, 10, H, W)`` float32, the network's image input (rgb in ``[0, 1]``, depth in m from
            the view's near face, xyz in m, pixel location; :meth:`abm.render.RenderedViews.rvt_channels`).
        view_mask: ``(V, H, W)`` float32, the mask channel the network saw (``None`` for rvt / ifd); abm's
            marks only the target's centre pixel.
        heatmaps: ``(V, H, W)`` float32, the predicted translation distribution of each view (sums to 1); the
            coarse stage's in a two-stage policy.
        zoom_center: two-stage policies: ``(3,)`` float32 world metres, the centre of the zoom cube (the coarse
            point); ``None`` for one stage.
        zoom_images: two-stage policies: ``(V, 10, h, w)`` float32, the zoomed views the second stage saw (xyz
            relative to ``zoom_center``).
        zoom_heatmaps: two-stage policies: ``(V, h, w)`` float32, the zoomed stage's translation distributions.
        view_destination_mask: ``(V, H, W)`` float32, the destination's mask channel the network saw (policies with
            ``destination_mask``; else ``None``).
    """

    action: KeyframeAction
    view_images: NDArray[np.float32]
    view_mask: NDArray[np.float32] | None
    heatmaps: NDArray[np.float32]
    zoom_center: NDArray[np.float32] | None = None
    zoom_images: NDArray[np.float32] | None = None
    zoom_heatmaps: NDArray[np.float32] | None = None
    view_destination_mask: NDArray[np.float32] | None = None


def proprioception(batch: Batch, config: PolicyConfig, workspace: Workspace, device: torch.device) -> torch.Tensor:
    """The network's proprioception input ``(B, config.proprio_size)`` float32 of a batch, in training and at
    inference alike (both build their samples with :func:`abm.samples.cloud_sample` from an observation):
    ``gripper_open`` (the measured finger opening in ``[0, 1]``), the gripper position in cube coordinates
    (``[-1, 1]`` inside the workspace), and with ``progress_input`` the keyframe index divided by
    ``progress_budget``, clipped to 1."""
    b = batch["gripper_position"].shape[0]
    grip_pos = batch["gripper_position"].to(device, torch.float32)
    center = torch.tensor(workspace.center, device=device, dtype=torch.float32)
    parts = [batch["gripper_open"].to(device, torch.float32).reshape(b, 1), (grip_pos - center) / float(workspace.half)]
    if config.progress_input:
        if "keyframe_index" not in batch:
            raise ValueError("progress_input needs each sample's keyframe_index (abm.samples.cloud_sample)")
        index = batch["keyframe_index"].to(device, torch.float32).reshape(b, 1)
        parts.append((index / float(config.progress_budget)).clamp(0.0, 1.0))
    return torch.cat(parts, -1)


def _occupied(images: torch.Tensor, renderer: OrthographicRenderer) -> NDArray[np.bool_]:
    """``(V, H, W)`` bool from ``(V, 10, H, W)`` RVT channels: the depth of an empty pixel is the cube's edge."""
    return (images[:, 3] < float(renderer.workspace.size) - 1e-6).cpu().numpy()


def _target_views(renderer: OrthographicRenderer, sample: Sample) -> tuple[torch.Tensor, NDArray[np.bool_] | None]:
    """Render a sample's cloud with its target mask: ``((V, 10, H, W)`` RVT channels, ``(V, H, W)`` bool target
    pixels or ``None``); the whole target as the views show it (abm's mask channel may mark less)."""
    dev = renderer.device
    mask = sample.get("point_mask")
    with torch.no_grad():
        views = renderer.render(sample["points"][None].to(dev), sample["colors"][None].to(dev),
                                extra=None if mask is None else mask[None, :, None].to(dev))
    target = None if mask is None else (views.extra[0, :, 0] > 0.5).cpu().numpy()
    return views.rvt_channels()[0].float().cpu(), target


def explain_grounding(observation: Observation, instruction: str, renderer: OrthographicRenderer, grounder: Grounder,
                  object_names: Mapping[int, str] | None = None,
                  camera_names: Sequence[str] | None = None) -> GroundingExplanation:
    """What a mask policy with ``renderer``'s views would see of ``observation``, without a network: fuse the
    cameras in the renderer's workspace, ground the target with ``grounder`` and render the views (the viewer's
    grounding-only scenes). :meth:`KeyframePolicy.explain` is the same with a policy."""
    scene = condition_cloud(observation, instruction, renderer.workspace, grounder=grounder, object_names=object_names,
                            mask=True, camera_names=list(camera_names) if camera_names else None)
    sample = cloud_sample(scene, observation.gripper_open, observation.gripper_pose[:3, 3],
                          keyframe_index=observation.step)
    images, target = _target_views(renderer, sample)
    return GroundingExplanation(sample=sample, target=scene.target, view_names=list(renderer.views),
                            view_rgb=images[:, :3].permute(0, 2, 3, 1).clamp(0, 1).numpy(),
                            view_occupied=_occupied(images, renderer), view_target=target)


class KeyframePolicy(nn.Module):
    """A keyframe policy of one variant (``abm``, ``rvt``, ``ifd`` or an ablation).

    Args:
        config: variant and sizes.
        language: language encoder, its configuration (:mod:`abm.policy.language_config`) or its dict form
            (``{"kind": "hash", ...}`` / ``{"kind": "clip", ...}``).
        grounder: grounder configuration (:mod:`abm.grounding.config`; its dict form ``{"kind": "clip", ...}``
            is read with ``grounder_config_from_dict``) or a grounder object with
            ``ground(observation, cloud, target, object_names)``; used by :meth:`act`.
        camera_names: cameras to fuse in :meth:`act` (default all of the observation's).
    """

    def __init__(
        self,
        config: PolicyConfig,
        language: LanguageEncoder | LanguageConfig | Mapping[str, Any],
        grounder: GrounderConfig | Mapping[str, Any] | Grounder | None = None,
        camera_names: Sequence[str] | None = None,
    ) -> None:
        super().__init__()
        self.config = config
        self.spec = config.spec
        # one stage: the network; two stages: the coarse, translation-only network (its state-dict keys are
        # those of a one-stage policy's network, so one-stage checkpoints load unchanged)
        self.model = MultiViewTransformer(config, rotation_head=not config.two_stage)
        self.zoom_model = MultiViewTransformer(config.zoom_config()) if config.two_stage else None
        self.language = (build_language_encoder(language) if isinstance(language, Mapping | LanguageConfig)
                         else language)
        if self.language.tokens != config.lang_tokens or self.language.dim != config.lang_dim:
            raise ConfigError(
                f"language encoder gives {self.language.tokens} x {self.language.dim} tokens but the policy "
                f"expects {config.lang_tokens} x {config.lang_dim}"
            )
        is_config = grounder is None or isinstance(grounder, (Mapping, GrounderConfig))
        # typed configuration of the grounder (None when a grounder object was given)
        self.grounder_config: GrounderConfig | None = (
            as_grounder_config(cast("GrounderConfig | Mapping[str, Any] | None", grounder)) if is_config else None)
        self._grounder: Grounder | None = None if is_config else cast("Grounder", grounder)
        self.camera_names = list(camera_names) if camera_names else None
        self.workspace = Workspace(config.workspace_center, config.workspace_size)
        self._renderer = OrthographicRenderer(self.workspace, config.resolution, config.views)
        zoom_cube = Workspace((0.0, 0.0, 0.0), config.zoom_size) if config.two_stage else None
        self._zoom_renderer = (OrthographicRenderer(zoom_cube, config.zoom_resolution, config.views)
                               if zoom_cube is not None else None)
        self._lang_cache: dict[str, torch.Tensor] = {}
        self.last_timings: dict[str, float] = {}
        self.checkpoint_path: str | None = None
        self._last_target: str | None = None  # the grounded object of the last observe()
        # kept out of the module tree (plain attributes), so state_dict keys never change
        self.__dict__["_compiled_model"] = None
        self.__dict__["_compiled_zoom_model"] = None
        self.cpu_bf16 = False

    # ------------------------------------------------------------------ parts
    @property
    def device(self) -> torch.device:
        return next(self.model.parameters()).device

    @property
    def renderer(self) -> OrthographicRenderer:
        """The virtual-view renderer, on the policy's device."""
        if self._renderer.device != self.device:
            self._renderer = self._renderer.to(self.device)
        return self._renderer

    @property
    def zoom_renderer(self) -> OrthographicRenderer | None:
        """The zoomed stage's renderer (a cube of edge ``zoom_size`` centred at the origin), on the policy's
        device; ``None`` for a one-stage policy."""
        if self._zoom_renderer is not None and self._zoom_renderer.device != self.device:
            self._zoom_renderer = self._zoom_renderer.to(self.device)
        return self._zoom_renderer

    def num_parameters(self) -> int:
        """Parameters of the network(s) (both stages of a two-stage policy)."""
        return self.model.num_parameters() + (self.zoom_model.num_parameters() if self.zoom_model else 0)

    @property
    def grounder_spec(self) -> dict[str, Any] | None:
        """The grounder configuration's dict form (what checkpoints store), ``None`` for a grounder object."""
        return None if self.grounder_config is None else self.grounder_config.to_dict()

    @property
    def grounder(self) -> Grounder:
        if self._grounder is None:
            self._grounder = build_grounder(self.grounder_config or OracleGrounderConfig())
        return self._grounder

    def reset(self) -> None:
        """Start a new episode: forget per-episode state (the tracking grounder's target)."""
        if self._grounder is not None and hasattr(self._grounder, "reset"):
            self._grounder.reset()

    def exact_memories(self) -> tuple[object, ...]:
        """The objects that only remember results this policy computes exactly the same again: the language
        tokens of each text, and those of its grounder when it has any (a CLIP grounder's backbone, text
        features, crop embeddings and results cache, also through a tracking grounder). A copy of the policy for
        another rollout may share them instead of copying them (:func:`abm.evaluation.policies.load_policy`).
        A grounder not built yet has none."""
        memories = getattr(self._grounder, "exact_memories", None) if self._grounder is not None else None
        return (self._lang_cache, *(memories() if memories is not None else ()))

    def sample_options(self) -> dict[str, bool]:
        """What the data pipeline must compute for this variant (``KeyframeDataset(**options)``)."""
        return {"split": self.spec.uses_mask or self.spec.language == "skill", "mask": self.spec.uses_mask,
                "features": self.spec.clip_features, "destination": self.config.destination_mask}

    def language_goal(self, instruction: str, skill: str) -> str:
        """The text the variant reads: the skill text (mask variants) or the whole instruction."""
        if self.spec.language == "skill":
            if not skill:
                raise ValueError(f"variant {self.spec.name!r} needs the skill text of {instruction!r}")
            return skill
        return instruction

    def encode_language(self, texts: Sequence[str]) -> torch.Tensor:
        """``(B, L, D)`` language tokens on the policy's device; each distinct text is encoded once."""
        todo = sorted({t for t in texts if t not in self._lang_cache})
        if todo:
            emb = self.language.encode(todo)
            self._lang_cache.update({t: emb[i].contiguous() for i, t in enumerate(todo)})
        return torch.stack([self._lang_cache[t] for t in texts]).to(self.device)

    # ------------------------------------------------------------------ batch -> model inputs
    def model_inputs(self, batch: Batch, zoom_center: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Render a batch of samples into the network's inputs, on the policy's device.

        Args:
            batch: collated samples.
            zoom_center: ``(B, 3)`` world metres: render the zoomed stage's views of the cube of edge
                ``zoom_size`` around each centre instead of the workspace views (two-stage policies only).

        Returns ``images`` ``(B, V, 10, H, W)``, ``proprio`` ``(B, proprio_size)`` (:func:`proprioception`),
        ``lang`` ``(B, L, D)``, and ``mask`` ``(B, V, M, H, W)`` (mask variants; ``M`` = 2 with ``destination_mask``:
        the target's channel, then the destination's) or ``ifd_features`` ``(B, M, F)`` + ``ifd_index``
        ``(B, V, H, W)`` (``ifd``); ``H = W`` is ``zoom_resolution`` for the zoomed views, whose xyz channels are
        relative to the zoom centre.
        """
        dev = self.device
        points = batch["points"].to(dev, torch.float32)
        renderer = self.renderer
        if zoom_center is not None:
            if self.zoom_renderer is None:
                raise ValueError("zoom_center given to a one-stage policy (zoom_size = 0)")
            renderer = self.zoom_renderer
            points = points - zoom_center.to(dev, torch.float32).reshape(-1, 1, 3)
        b, n, _ = points.shape
        valid = batch["valid"].to(dev) if "valid" in batch else None
        extra = []
        if self.spec.uses_mask:
            if "point_mask" not in batch:
                raise ValueError(f"variant {self.spec.name!r} needs a per-point mask field (point_mask)")
            extra += [batch["point_mask"].to(dev, torch.float32), batch["point_heatmap"].to(dev, torch.float32)]
            if self.config.destination_mask:
                if "destination_mask" not in batch:
                    raise ValueError("destination_mask needs the destination's per-point mask field (destination_mask)")
                extra += [batch["destination_mask"].to(dev, torch.float32),
                          batch["destination_heatmap"].to(dev, torch.float32)]
        if self.spec.clip_features:
            if "feature_table" not in batch or "feature_row" not in batch:
                raise ValueError(f"variant {self.spec.name!r} needs per-point CLIP features (feature_table and "
                                 "feature_row)")
            extra.append(batch["feature_row"].to(dev, torch.float32))  # each pixel: its point's table row (exact)
        with torch.no_grad():
            views = renderer.render(points, batch["colors"].to(dev, torch.float32),
                                    extra=torch.stack(extra, -1) if extra else None, valid=valid)
        inputs = {"images": views.rvt_channels().contiguous()}
        if self.spec.uses_mask:
            channels = [mask_channel(self.spec, views.extra[:, :, 2 * i:2 * i + 2])
                        for i in range(self.config.mask_channels)]
            inputs["mask"] = (torch.cat(channels, 2) if len(channels) > 1 else channels[0]).contiguous()
        if self.spec.clip_features:
            inputs["ifd_features"], inputs["ifd_index"] = self._visible_features(
                batch["feature_table"].to(dev), views.extra[:, :, -1], views.occupied)
        inputs["proprio"] = proprioception(batch, self.config, self.workspace, dev)
        inputs["lang"] = self.encode_language(
            [self.language_goal(i, s) for i, s in zip(batch["instruction"], batch["skill"], strict=True)])
        return inputs

    def _visible_features(self, features: torch.Tensor, index: torch.Tensor, occupied: torch.Tensor
                          ) -> tuple[torch.Tensor, torch.Tensor]:
        """Keep the feature-table rows seen in some view (``index``: ``(B, V, H, W)`` the table row rendered
        in each pixel): ``(B, M, F)`` float32 and the views' index into them ``(B, V, H, W)`` (-1 = empty
        pixel)."""
        if features.shape[-1] != self.config.ifd_feature_dim:
            raise ConfigError(f"CLIP point features have width {features.shape[-1]}, expected "
                              f"{self.config.ifd_feature_dim}; set the policy's ifd_feature_dim to the CLIP width")
        idx = torch.where(occupied, index.round().long(), torch.full_like(index, -1, dtype=torch.long))
        kept, compact = [], torch.full_like(idx, -1)
        for i in range(idx.shape[0]):
            seen = idx[i] >= 0
            visible, inverse = torch.unique(idx[i][seen], return_inverse=True)
            compact[i][seen] = inverse
            kept.append(features[i, visible].float())
        m = max(max(k.shape[0] for k in kept), 1)
        out = features.new_zeros((len(kept), m, features.shape[-1]), dtype=torch.float32)
        for i, k in enumerate(kept):
            out[i, : k.shape[0]] = k
        return out, compact

    def targets(self, batch: Batch) -> dict[str, torch.Tensor]:
        """Training targets: per-view heatmaps ``(B, V, H, W)``, rotation bins ``(B, 3)``, gripper and
        collision classes ``(B,)``."""
        dev = self.device
        quat = batch["action_quaternion"].detach().cpu().numpy()
        bins = np.asarray(quat_to_bins(quat, self.config.rotation_bins), np.int64).reshape(-1, 3)
        return {
            "heatmap": translation_targets(self.renderer, batch["action_position"].to(dev, torch.float32)),
            "rotation_bins": torch.from_numpy(bins).to(dev),
            "gripper": batch["action_gripper"].to(dev),
            "collision": batch["action_collision"].to(dev),
        }

    def compile_network(self, enabled: bool = True, backend: str = "inductor") -> KeyframePolicy:
        """Run the network through ``torch.compile`` from now on (``enabled=False`` goes back to eager); the
        module itself, its parameters and checkpoint keys are unchanged. With TorchInductor, compiling costs
        ~50 s at the first step on 2 CPU cores and pays off in long runs (``benchmarks/train_speed.py
        --compile``, docs/performance.md)."""
        self.__dict__["_compiled_model"] = torch.compile(self.model, backend=backend) if enabled else None
        self.__dict__["_compiled_zoom_model"] = (torch.compile(self.zoom_model, backend=backend)
                                                 if enabled and self.zoom_model is not None else None)
        return self

    def use_cpu_bf16(self, mode: str = "auto") -> bool:
        """bf16 autocast on CPU: ``on``, ``off`` or ``auto`` (= off on the CPU). Returns the choice.

        ``auto`` stays in float32: with the channels-last network, bf16 autocast made a training step 1.3x slower
        even on a CPU where oneDNN reports native bf16 (the casts of the full-resolution maps cost more than the
        bf16 matrix products save; docs/performance.md), and emulated bf16 is 5-10x slower. ``on`` forces it."""
        if mode not in ("auto", "on", "off"):
            raise ValueError(f"bf16 mode must be 'auto', 'on' or 'off', not {mode!r}")
        self.cpu_bf16 = mode == "on"
        return self.cpu_bf16

    def run_model(self, inputs: Mapping[str, torch.Tensor], pool_weights: torch.Tensor | None = None,
                  zoom: bool = False) -> PolicyOutput:
        """One network on prepared inputs (bf16 autocast on CUDA, and on CPU after :meth:`use_cpu_bf16`): the
        workspace network, or with ``zoom`` the zoomed stage's (inputs from ``model_inputs(batch, zoom_center)``)."""
        dev = self.device.type
        autocast = dev == "cuda" or (dev == "cpu" and self.cpu_bf16)
        if zoom and self.zoom_model is None:
            raise ValueError("this policy has one stage (zoom_size = 0)")
        compiled = self.__dict__["_compiled_zoom_model" if zoom else "_compiled_model"]
        network = self.zoom_model if zoom else self.model
        assert network is not None  # checked above
        model = compiled if compiled is not None else network
        with torch.autocast(device_type=dev, dtype=torch.bfloat16, enabled=autocast):
            out: PolicyOutput = model(inputs["images"], inputs["proprio"], inputs["lang"], mask=inputs.get("mask"),
                        ifd_features=inputs.get("ifd_features"), ifd_index=inputs.get("ifd_index"),
                        pool_weights=pool_weights)
        return out

    # ------------------------------------------------------------------ training / inference
    def forward(self, batch: Batch) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Loss of a batch of samples with targets: ``(total loss, detached loss terms)``.

        The rotation/gripper head pools at the ground-truth heatmap (as RVT-2 does in training); a two-stage
        policy adds the zoomed stage's heatmap term (``zoom_translation``). See :meth:`teacher_forced`.
        """
        out, target = self.teacher_forced(batch)
        terms = policy_loss(out, target["heatmap"], target["rotation_bins"], target["gripper"], target["collision"],
                            coarse_target=target.get("coarse_heatmap"))
        metrics = {k: getattr(terms, k).detach() for k in LOSS_TERMS}
        return terms.total, metrics

    def teacher_forced(self, batch: Batch) -> tuple[PolicyOutput, dict[str, torch.Tensor]]:
        """The network output of a batch with targets as in training, and the targets (:meth:`targets`).

        The rotation/gripper head pools at the label's heatmap. A two-stage policy zooms on the label (plus
        uniform noise of ``zoom_noise`` m per axis in training mode); its targets' ``heatmap`` is then the
        zoomed views' and ``coarse_heatmap`` the workspace views'.
        """
        inputs = self.model_inputs(batch)
        target = self.targets(batch)
        if self.zoom_model is None:
            return self.run_model(inputs, pool_weights=target["heatmap"]), target
        coarse = self.run_model(inputs)
        position = batch["action_position"].to(self.device, torch.float32)
        noise = self.config.zoom_noise if self.training else 0.0
        center = position + (torch.rand_like(position) * 2.0 - 1.0) * noise
        assert self.zoom_renderer is not None  # built with the zoom model
        zoom_target = translation_targets(self.zoom_renderer, position - center)
        fine = self.run_model(self.model_inputs(batch, zoom_center=center), pool_weights=zoom_target, zoom=True)
        out = PolicyOutput(fine.heatmap, fine.rotation, fine.gripper, fine.collision, coarse_heatmap=coarse.heatmap,
                           zoom_center=center)
        return out, {**target, "heatmap": zoom_target, "coarse_heatmap": target["heatmap"]}

    def compute_loss(self, batch: Batch) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Same as calling the module (so ``DistributedDataParallel`` wrapping works)."""
        loss: tuple[torch.Tensor, dict[str, torch.Tensor]] = self(batch)
        return loss

    @torch.no_grad()
    def infer(self, batch: Batch, inputs: Mapping[str, torch.Tensor] | None = None
              ) -> tuple[PolicyOutput, dict[str, torch.Tensor] | None]:
        """The network output of a batch at inference: one stage, or the coarse stage, then the zoomed stage
        around the coarse point. Returns the output and the zoomed inputs (``None`` for one stage); ``inputs``
        are the batch's workspace inputs when already rendered."""
        out = self.run_model(inputs if inputs is not None else self.model_inputs(batch))
        if self.zoom_model is None:
            return out, None
        center = decode_translation(out.heatmap, self.renderer)
        zoom_inputs = self.model_inputs(batch, zoom_center=center)
        fine = self.run_model(zoom_inputs, zoom=True)
        return PolicyOutput(fine.heatmap, fine.rotation, fine.gripper, fine.collision, coarse_heatmap=out.heatmap,
                            zoom_center=center), zoom_inputs

    def decode(self, out: PolicyOutput) -> list[KeyframeAction]:
        """Keyframe actions of a network output (one- or two-stage)."""
        return decode_output(out, self.renderer, self.zoom_renderer)

    @torch.no_grad()
    def predict(self, batch: Batch) -> list[KeyframeAction]:
        """One keyframe action per sample of the batch (heatmaps decoded to a 3-D point, bins to a rotation)."""
        return self.decode(self.infer(batch)[0])

    def observe(self, observation: Observation, instruction: str,
                object_names: Mapping[int, str] | None = None) -> Sample:
        """The sample of one observation (fuse, split the instruction, ground), as the dataset makes it."""
        opts = self.sample_options()
        if opts["mask"] and isinstance(self.grounder_config, OracleGrounderConfig) and object_names is None:
            raise ConfigError("the oracle grounder needs object_names (segmentation id -> name)")
        needs_grounder = opts["mask"] or opts["features"]
        scene = condition_cloud(observation, instruction, self.workspace,
                                grounder=self.grounder if needs_grounder else None, object_names=object_names,
                                split=opts["split"], mask=opts["mask"], features=opts["features"],
                                camera_names=self.camera_names, destination=opts["destination"])
        self._last_target = scene.target  # for explain()
        return cloud_sample(scene, observation.gripper_open, observation.gripper_pose[:3, 3],
                            keyframe_index=observation.step)

    def act(self, observation: Observation, instruction: str,
            object_names: Mapping[int, str] | None = None) -> KeyframeAction:
        """The next keyframe for ``observation`` under ``instruction``.

        Args:
            observation: the current cameras and gripper state.
            instruction: the full English instruction.
            object_names: segmentation id -> object name (needed by the oracle grounder, and used to
                find the target in the instruction when no decomposition template matches).

        Seconds per stage of the last call are in :attr:`last_timings`: ``condition_s`` (fusion, instruction
        split, grounding), ``render_s`` (virtual views, language tokens), ``model_s`` (with a zoomed stage: both
        networks and the zoom's rendering) and ``decode_s``.
        """
        return self._step(observation, instruction, object_names)[3]

    def explain(self, observation: Observation, instruction: str,
                object_names: Mapping[int, str] | None = None) -> PolicyExplanation:
        """:meth:`act` plus what the policy saw and where it looked (for viewers and reports)."""
        sample, inputs, out, action, zoom_inputs = self._step(observation, instruction, object_names)
        images = inputs["images"][0].float().cpu()

        def distribution(logits: torch.Tensor) -> NDArray[np.float32]:
            return torch.softmax(logits.float().flatten(1), -1).view_as(logits).cpu().numpy().astype(np.float32)

        coarse = out.heatmap[0] if out.coarse_heatmap is None else out.coarse_heatmap[0]
        heat = distribution(coarse)
        zoom = {}
        if out.zoom_center is not None and zoom_inputs is not None:
            zoom = {"zoom_center": out.zoom_center[0].float().cpu().numpy(),
                    "zoom_images": zoom_inputs["images"][0].float().cpu().numpy(),
                    "zoom_heatmaps": distribution(out.heatmap[0])}
        mask = inputs.get("mask")
        target = _target_views(self.renderer, sample)[1] if "point_mask" in sample else None
        return PolicyExplanation(
            action=action,
            sample=sample,
            target=self._last_target,
            view_names=list(self.renderer.views),
            view_rgb=images[:, :3].permute(0, 2, 3, 1).clamp(0, 1).numpy(),
            view_occupied=_occupied(images, self.renderer),
            view_target=target,
            view_images=images.numpy(),
            view_mask=None if mask is None else mask[0, :, 0].float().cpu().numpy(),
            view_destination_mask=(mask[0, :, 1].float().cpu().numpy()
                                   if mask is not None and self.config.destination_mask else None),
            heatmaps=heat,
            **zoom,
        )

    def _step(self, observation: Observation, instruction: str, object_names: Mapping[int, str] | None
              ) -> tuple[Sample, dict[str, torch.Tensor], PolicyOutput, KeyframeAction, dict[str, torch.Tensor] | None]:
        sync = torch.cuda.synchronize if self.device.type == "cuda" else (lambda *_: None)
        t0 = time.perf_counter()
        sample = self.observe(observation, instruction, object_names)
        batch = collate([sample])
        t1 = time.perf_counter()
        with torch.no_grad():
            inputs = self.model_inputs(batch)
            sync(self.device)
            t2 = time.perf_counter()
            out, zoom_inputs = self.infer(batch, inputs)
            sync(self.device)
        t3 = time.perf_counter()
        action = self.decode(out)[0]
        self.last_timings = {"condition_s": t1 - t0, "render_s": t2 - t1, "model_s": t3 - t2,
                             "decode_s": time.perf_counter() - t3}
        return sample, inputs, out, action, zoom_inputs

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_payload(self) -> dict[str, Any]:
        """What a checkpoint needs to rebuild this policy (training adds its own state)."""
        return {
            "policy_config": self.config.to_dict(), "variant": self.config.variant, "preset": self.config.preset,
            "language": self.language.spec(), "grounder": self.grounder_spec,  # the config's dict form
            "camera_names": self.camera_names,
            "model": self.model.state_dict(),
            **({"zoom_model": self.zoom_model.state_dict()} if self.zoom_model is not None else {}),
        }

    def load_networks(self, payload: Mapping[str, Any]) -> None:
        """Load the network weights of a checkpoint payload (``model``, and ``zoom_model`` for two stages)."""
        self.model.load_state_dict(payload["model"])
        if self.zoom_model is not None:
            if "zoom_model" not in payload:
                raise CheckpointError("the checkpoint has no zoomed stage (zoom_model) but the policy config has one")
            self.zoom_model.load_state_dict(payload["zoom_model"])

    def save(self, path: str | Path, **extra: object) -> Path:
        """Write an inference checkpoint (plus ``extra`` entries) atomically; returns the path."""
        return save_checkpoint(path, {**self.checkpoint_payload(), **extra})

    @classmethod
    def from_checkpoint(
        cls,
        run_or_ckpt: str | Path,
        device: str | torch.device = "cpu",
        grounder: GrounderConfig | Mapping[str, Any] | Grounder | None = None,
        expect_variant: str | None = None,
    ) -> KeyframePolicy:
        """Load a checkpoint file or the latest checkpoint of a run folder, in eval mode on ``device``.

        Args:
            run_or_ckpt: ``RUN/`` or ``RUN/checkpoints/step_XXXXXXXX.pt``.
            device: where to run.
            grounder: override the grounder stored in the checkpoint (configuration, its dict form, or a
                grounder object); a configuration of the same kind only overrides the options it names
                (:func:`abm.grounding.config.merge_grounder_configs`).
            expect_variant: if given, a checkpoint of another variant raises :class:`~abm.errors.CheckpointError`.
        """
        ckpt = load_checkpoint(run_or_ckpt, map_location="cpu")
        try:
            config = PolicyConfig.from_dict(ckpt["policy_config"])
        except ValueError as err:  # PolicyConfig's checks of the stored values (unknown fields: a newer abm's)
            raise CheckpointError(f"{ckpt['path']}: its policy settings cannot be read ({err})") from err
        if expect_variant is not None and config.variant != expect_variant:
            raise CheckpointError(f"checkpoint {ckpt['path']} is a {config.variant!r} policy, expected "
                                  f"{expect_variant!r}")
        stored = ckpt.get("grounder")  # the dict form (file boundary)
        stored_config = grounder_config_from_dict(stored) if stored is not None else None
        if grounder is None or isinstance(grounder, (Mapping, GrounderConfig)):
            override = as_grounder_config(grounder) if grounder is not None else None
            grounder = merge_grounder_configs(stored_config, override)
        policy = cls(config, ckpt["language"], grounder, ckpt.get("camera_names"))
        policy.load_networks(ckpt)
        policy.checkpoint_path = ckpt["path"]
        return policy.to(device).eval()
