"""``abm ground``: decompose an instruction, ground its target and write inspection PNGs.

Works on one keyframe of an episode file (``--episode FILE --step K``) or on the built-in synthetic
sample scene (default). Writes to ``--out``:

* ``camera_<name>.png`` — each camera image, its heatmap overlay and its mask overlay, side by side;
* ``topdown.png`` — the mask field seen from above (RGB, heatmap, mask) over the workspace;
* ``views.png`` / ``view_<name>.png`` — the five virtual views with the center pixel marked, above the
  re-rendered binary mask;
* ``summary.json`` — instruction, target, skill, prompt, point counts, mask centre, the scene's objects, and how
  the instruction was resolved onto them (``resolved``: :func:`abm.language.resolve.resolve_instruction`, so
  "grab the yellow one" grounds the scene's ``yellow block``).

A target ``abm run`` would refuse (:func:`abm.grounding.decision.decide_target`: a name the scene does not hold,
several candidates, not found by the grounder, or found without confidence) is a warning naming the objects the
scene holds and the candidates, a red "NOT FOUND" caption on the images, and, with ``--strict``, a non-zero exit.
"""

from __future__ import annotations

import argparse
import json
import logging
from typing import TYPE_CHECKING, Any

from abm.data.episode_store import load_episode
from abm.errors import ConfigError, ExternalError, OutputError, RefusedError
from abm.files import write_text_atomic
from abm.geometry import Workspace, fuse_cameras
from abm.grounding.config import GROUNDERS, GrounderConfig, build_grounder, grounder_config_from_dict
from abm.grounding.decision import decide_target
from abm.grounding.default import default_grounder
from abm.grounding.grounders import ClipGrounder
from abm.grounding.mask_field import mask_views
from abm.grounding.visualize import blend, colormap, gray, hstack, label, mark_pixels, to_uint8, upscale, vstack
from abm.language.instruction import InstructionError, decompose_instruction
from abm.language.resolve import Resolution, UnresolvedInstructionError, resolve_instruction
from abm.render import OrthographicRenderer
from abm.render.synthetic import synthetic_scene

if TYPE_CHECKING:  # numpy is imported by the command itself, so `abm --help` stays fast
    import numpy as np


def _load_observation(args: argparse.Namespace) -> tuple[Any, dict[int, str], str | None, str]:
    """(observation, object names, episode instruction or None, description)."""
    if args.episode is not None:
        episode = load_episode(args.episode)
        if not 0 <= args.step < len(episode.steps):
            raise ConfigError(f"--step {args.step} is out of range: the episode has {len(episode.steps)} keyframes")
        obs = episode.steps[args.step][0]
        return obs, dict(episode.object_names), episode.instruction, f"{args.episode} step {args.step}"

    obs, names = synthetic_scene(seed=args.seed)
    return obs, names, None, f"synthetic scene (seed {args.seed})"


def _camera_panels(obs: Any, cloud: Any, field: Any) -> dict[str, np.ndarray]:
    import numpy as np


    panels = {}
    for ci, name in enumerate(cloud.camera_names):
        frame = obs.camera(name)
        sel = cloud.camera_index == ci
        rows, cols = cloud.pixels[sel, 0], cloud.pixels[sel, 1]
        heat = np.zeros(frame.rgb.shape[:2], np.float32)
        mask = np.zeros(frame.rgb.shape[:2], np.float32)
        has = np.zeros(frame.rgb.shape[:2], bool)
        heat[rows, cols] = field.heatmap[sel]
        mask[rows, cols] = field.mask[sel]
        has[rows, cols] = True
        dim = blend(frame.rgb, np.zeros_like(frame.rgb), 0.5)
        heat_img = np.where(has[..., None], blend(frame.rgb, colormap(heat), 0.3 + 0.5 * heat), dim)
        red = np.zeros_like(frame.rgb)
        red[..., 0] = 255
        mask_img = np.where(has[..., None], blend(frame.rgb, red, 0.7 * mask), dim)
        panels[name] = hstack([label(upscale(frame.rgb, 2), name), label(upscale(heat_img, 2), "heatmap"),
                               label(upscale(mask_img, 2), "mask")])
    return panels


def _topdown(cloud: Any, field: Any, workspace: Any, resolution: int = 256) -> np.ndarray:
    import numpy as np
    import torch


    renderer = OrthographicRenderer(workspace, resolution, views=("top",), splat_radius=1)
    extra = torch.from_numpy(np.stack([field.heatmap, field.mask], axis=1))
    out = renderer.render(torch.from_numpy(cloud.xyz), torch.from_numpy(cloud.rgb), extra=extra)
    rgb = to_uint8(out.rgb[0, 0].permute(1, 2, 0).numpy())
    occ = out.occupied[0, 0].numpy()[..., None]
    heat = np.where(occ, colormap(out.extra[0, 0, 0].numpy()), 0).astype(np.uint8)
    red = np.zeros_like(rgb)
    red[..., 0] = 255
    mask = blend(rgb, red, 0.8 * out.extra[0, 0, 1].numpy())
    return hstack([label(rgb, "top: RGB (up = +x)"), label(heat, "heatmap"), label(mask, "mask")])


def _grounder_config(args: argparse.Namespace) -> GrounderConfig:
    """The typed configuration of ``--grounder`` and its options (those of a grounder that uses a CLIP: its
    weights, device, cache, mask-field and proposal settings)."""
    proposal_flags = ("mode", "dense_mode", "input_size", "scoring", "scales")
    tuning = {k: v for k in proposal_flags if (v := getattr(args, k)) is not None}
    if args.normalization:
        tuning["normalization"] = args.normalization
    if args.threshold is not None:
        tuning["threshold"] = args.threshold
    if not GROUNDERS[args.grounder].clip:
        if any(k in tuning for k in proposal_flags):
            raise ConfigError("--mode, --dense-mode, --input-size, --scales and --scoring apply to --grounder "
                              f"{' or '.join(GROUNDERS.names(per_frame=True, clip=True))} only")
        if tuning or args.clip_model:
            raise ConfigError("--clip-model, --normalization and --threshold apply to --grounder "
                              f"{' or '.join(GROUNDERS.names(per_frame=True, clip=True))} only")
        return grounder_config_from_dict({"kind": args.grounder})
    clip = {"device": args.device, "allow_download": args.allow_download, "cache": args.cache}
    if args.clip_model:
        clip["model"] = args.clip_model
    return grounder_config_from_dict({"kind": args.grounder, **clip, **tuning})


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import torch
    from PIL import Image


    if args.instruction is not None and not args.instruction.strip():
        raise ConfigError("--instruction is empty; give the instruction to ground, or leave the option out")
    if args.out.exists() and not args.out.is_dir():
        raise OutputError(f"--out {args.out} is a file; give a folder")
    if str(args.device).startswith("cuda") and not torch.cuda.is_available():
        raise ExternalError(f"--device {args.device}: CUDA is not available on this machine (use --device cpu)")
    obs, names, episode_instruction, where = _load_observation(args)
    instruction = args.instruction or episode_instruction or f"put the {next(iter(names.values()))} in the plate"
    target, skill, resolution = _resolve(instruction, names)
    workspace = Workspace()
    cloud = fuse_cameras(obs, workspace)

    if args.clip_model and (args.grounder is None or GROUNDERS[args.grounder].clip):  # named: loading it says
        args.grounder = args.grounder or "clip"  # what is wrong, if anything
        print(f"abm ground: grounder: CLIP {args.clip_model} (--clip-model)")
    elif args.grounder is None or GROUNDERS[args.grounder].clip:  # no --grounder, or clip without --clip-model:
        # the order every command uses
        choice = default_grounder(args.clip_model, str(args.device), download=args.allow_download,
                                  clip_only=args.grounder is not None)
        args.grounder, args.clip_model = choice.kind, choice.model
        print(choice.startup_line("ground"))
    else:
        print(f"abm ground: grounder: {args.grounder} (--grounder {args.grounder}: "
              f"{GROUNDERS[args.grounder].description})")
    grounder = build_grounder(_grounder_config(args))
    field = grounder.ground(obs, cloud, target, names)
    scene_objects = sorted(set(names.values()))
    decision = decide_target(field, target, names, grounder=args.grounder)  # the one abm run acts on
    missing = not decision.found
    notice = f"target {target!r} NOT FOUND" if missing else ""

    renderer = OrthographicRenderer(workspace, args.resolution, splat_radius=1, device=args.device)
    views = renderer.render(torch.from_numpy(cloud.xyz), torch.from_numpy(cloud.rgb))
    mviews = mask_views(renderer, cloud, field.mask)

    args.out.mkdir(parents=True, exist_ok=True)
    for name, panel in _camera_panels(obs, cloud, field).items():
        Image.fromarray(_flag(panel, notice)).save(args.out / f"camera_{name}.png")
    Image.fromarray(_flag(_topdown(cloud, field, workspace), notice)).save(args.out / "topdown.png")
    tiles = []
    for vi, view in enumerate(renderer.views):
        rgb = upscale(to_uint8(views.rgb[0, vi].permute(1, 2, 0).cpu().numpy()), 2)
        rows, cols = np.nonzero(mviews.center[vi].cpu().numpy())
        rgb = mark_pixels(rgb, [(2 * int(r) + 1, 2 * int(c) + 1) for r, c in zip(rows, cols, strict=True)], radius=7)
        full = upscale(gray(mviews.full[vi].cpu().numpy()), 2)
        tile = vstack([label(rgb, f"{view} (center pixel marked)"), label(full, "re-rendered mask")])
        Image.fromarray(_flag(tile, notice)).save(args.out / f"view_{view}.png")
        tiles.append(tile)
    Image.fromarray(_flag(hstack(tiles), notice)).save(args.out / "views.png")

    center = field.center(cloud.xyz)
    summary = {
        "scene": where, "instruction": instruction, "target": target, "skill": skill,
        "grounder": args.grounder, "prompt": field.prompt, "found": field.found,
        "confidence": round(float(field.confidence or 0.0), 4), "decision": decision.as_record(),
        "points": len(cloud), "mask_points": int(field.mask.sum()),
        "mask_center_m": None if center is None else [round(float(c), 4) for c in center],
        "scene_objects": scene_objects, "target_in_scene": target in scene_objects,
        "resolved": None if resolution is None else resolution.as_record(),
        "center_pixels": {v: [int(x) for x in np.argwhere(mviews.center[i].cpu().numpy()).reshape(-1)]
                          for i, v in enumerate(renderer.views)},
    }
    if isinstance(grounder, ClipGrounder):  # --grounder clip
        summary.update(model=grounder.backbone.name, model_fingerprint=grounder.model_name,
                       normalization=grounder.config.normalization,
                       threshold=grounder.config.threshold)
        summary.update(mode=grounder.mode, dense_mode=grounder.dense_mode, input_size=grounder.input_size,
                       scales=list(grounder.scales))
        if grounder.mode == "proposals":
            summary["scoring"] = grounder.proposal_config.scoring
    write_text_atomic(args.out / "summary.json", json.dumps(summary, indent=2) + "\n")
    print(f"{where}: {instruction!r} -> target {target!r}, skill {skill!r}")
    if resolution is not None and resolution.method != "templates":
        print(f"read as {resolution.canonical!r} (confidence {resolution.confidence:.2f}, by {resolution.method}; "
              f"{resolution.phrase!r} is the scene's {resolution.target!r})")
    print(f"{args.grounder} grounder: {summary['mask_points']} of {len(cloud)} points masked, found={field.found}, "
          f"confidence {summary['confidence']:.2f}")
    print(f"wrote camera_*.png, topdown.png, views.png, view_*.png and summary.json to {args.out}/")
    if missing:
        message = f"{decision.message(instruction)} (the images are marked NOT FOUND)"
        if args.strict:
            raise RefusedError(f"{message}; --strict")
        logging.getLogger("abm").warning("abm ground: WARNING: %s", message)
    return 0


def _resolve(instruction: str, names: dict[int, str]) -> tuple[str, str, Resolution | None]:
    """``(target X, skill, resolution)``: the instruction resolved onto the scene's objects
    (:func:`abm.language.resolve.resolve_instruction`, as ``abm run`` does), or, when that is refused but the
    templates name an object, the templates' X as written (the decision then says what the scene lacks)."""
    try:
        resolution = resolve_instruction(instruction, names)
    except UnresolvedInstructionError as err:
        try:
            target, skill = decompose_instruction(instruction)
        except InstructionError:
            raise err from None
        return target, skill, None
    return resolution.target, resolution.skill, resolution


def _flag(image: np.ndarray, notice: str) -> np.ndarray:
    """``image`` with a red caption strip saying ``notice`` on top (unchanged when there is none)."""
    if not notice:
        return image
    import numpy as np
    from PIL import Image, ImageDraw

    strip = Image.new("RGB", (image.shape[1], 16), (200, 0, 0))
    ImageDraw.Draw(strip).text((3, 2), notice, fill=(255, 255, 255))
    return np.concatenate([np.asarray(strip), image], axis=0)
