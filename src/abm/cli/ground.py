"""``abm ground``: decompose an instruction, ground its target and write inspection PNGs.

Works on one keyframe of an episode file (``--episode FILE --step K``) or on the built-in synthetic
sample scene (default). Writes to ``--out``:

* ``camera_<name>.png`` — each camera image, its heatmap overlay and its mask overlay, side by side;
* ``topdown.png`` — the mask field seen from above (RGB, heatmap, mask) over the workspace;
* ``views.png`` / ``view_<name>.png`` — the five virtual views with the center pixel marked, above the
  re-rendered binary mask;
* ``summary.json`` — instruction, target, skill, prompt, point counts, mask centre, the scene's objects.

A target ``abm run`` would refuse (:func:`abm.grounding.decision.decide_target`: a name the scene does not hold,
several candidates, not found by the grounder, or found without confidence) is a warning naming the objects the
scene holds and the candidates, a red "NOT FOUND" caption on the images, and, with ``--strict``, a non-zero exit.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from abm.configuration import clip_model_help, count, float_range, int_range, seed_int
from abm.grounding.config import CLIP_MODES, DENSE_MODES, GROUNDERS, NORMALIZATIONS, SCORINGS


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "ground",
        help="ground an instruction's target object and write heatmap / mask / virtual-view PNGs",
        description="Resolve the instruction (in plain words) onto the scene's objects, split it into the target X "
        "and the skill, compute the Object Mask Field "
        "of X over the fused point cloud (CLIP or oracle grounder), render it into the five virtual views "
        "and write PNGs. Without --episode the built-in synthetic scene is used.",
    )
    p.add_argument("--episode", type=Path, help="episode file (abm.data.episode_store format)")
    p.add_argument("--step", type=count, default=0, help="keyframe index within the episode (default 0)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the synthetic scene (without --episode)")
    p.add_argument("--instruction", help="instruction, in plain words ('grab the yellow one'; default: the "
                   "episode's, or one naming a scene object)")
    p.add_argument("--grounder", choices=GROUNDERS.names(per_frame=True), default=None,
                   help="grounder (default: --clip-model if given, else the pretrained CLIP if cached, else the "
                   "committed benchmark CLIP (models/benchmark-clip), else the oracle with a warning)")
    p.add_argument("--clip-model", default=None,
                   help=clip_model_help("of the CLIP grounder (needs them locally unless --allow-download)",
                                        default="the pretrained CLIP if cached, else the benchmark CLIP"))
    p.add_argument("--allow-download", action="store_true", help="let transformers download CLIP weights")
    p.add_argument("--normalization", choices=NORMALIZATIONS, default=None,
                   help="heatmap normalisation (default softmax)")
    p.add_argument("--threshold", type=float_range(0.0, 1.0), default=None,
                   help="mask threshold on the heatmap (default 0.7)")
    p.add_argument("--mode", choices=CLIP_MODES, default=None,
                   help="clip: threshold the per-point field, or score 3-D object proposals and mark the best one")
    p.add_argument("--dense-mode", choices=DENSE_MODES, default=None,
                   help="clip: last block of the dense CLIP features")
    p.add_argument("--input-size", type=int_range(32, 2048), default=None,
                   help="clip: side the camera images are resized to")
    p.add_argument("--scales", type=int_range(32, 2048), nargs="+", default=None,
                   help="clip: extra input sides whose features are averaged in (multi-scale), e.g. --scales 256")
    p.add_argument("--scoring", choices=SCORINGS, default=None,
                   help="clip --mode proposals: score candidates by dense features, image crops or both")
    p.add_argument("--cache", type=Path, default=None, help="grounding cache folder (default: none)")
    p.add_argument("--resolution", type=int_range(16, 2048), default=220, help="virtual view side in pixels")
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    p.add_argument("--out", type=Path, default=Path("out/ground"), help="output folder (default out/ground)")
    p.add_argument("--strict", action="store_true",
                   help="exit non-zero (after writing the images) when abm run would refuse the target: not in "
                   "the scene, ambiguous, not found by the grounder, or found without confidence")
    p.set_defaults(func="abm.cli.commands.ground:run")
