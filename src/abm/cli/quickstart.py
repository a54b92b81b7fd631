"""``abm quickstart``: the whole method end to end on a laptop CPU, with no arguments.

1. generate a small set of expert demonstrations (seen objects) for the trainable tasks;
2. train the ``small`` ``abm`` policy and the ``rvt`` baseline on them;
3. evaluate both on the same seeded scenes with seen and with unseen objects;
4. write a report folder: the success table, training curves, the virtual views with the mask,
   and rollout GIFs.

Every stage resumes: re-running the command skips finished episodes, continues training from the
last checkpoint and skips finished evaluation episodes.
"""

from __future__ import annotations

import argparse
import functools
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from abm.cli.train import POLICY_DEST, parse_override
from abm.configuration import CAMERA_RESOLUTION, add_config_arguments, load_recipe
from abm.experiments.spec import ExperimentSpec, load_spec
from abm.measured import quickstart_text
from abm.policy.config import PolicyConfig
from abm.policy.variants import VARIANTS
from abm.train.config import preset_policy

#: The quickstart's training recipe (``configs/quickstart.yaml``; also ``abm train --config quickstart``): steps,
#: batch, optimiser, lr, warm-up, checkpoint interval, and under ``policy`` the small preset's changes: 48-pixel
#: views with 6-pixel patches over a 0.6 m workspace cube fitted to the table. Measured in docs/evaluation.md.
RECIPE = "quickstart"


#: The quickstart's experiment (``configs/experiments/quickstart.yaml``): its tasks, demonstrations, methods and
#: evaluation are the flags' defaults; ``abm quickstart`` runs it with the flags applied (``abm.experiments``).
SPEC = "quickstart"


@functools.cache
def recipe() -> dict[str, Any]:
    """The quickstart recipe's values (:data:`RECIPE`)."""
    return load_recipe(RECIPE)


@functools.cache
def spec() -> ExperimentSpec:
    """The quickstart's experiment spec (:data:`SPEC`), read for the flags' defaults: its task names are checked
    when the quickstart generates its data, not here, so ``abm --help`` imports no simulator module."""
    return load_spec(SPEC, check_tasks=False)


@dataclass
class QuickstartConfig:
    """Sizes of the quickstart run (the ``abm quickstart`` flags; what the defaults measured: docs/evaluation.md).

    The training defaults come from the quickstart recipe (``configs/quickstart.yaml``, :data:`RECIPE`): the CPU
    recipe of the seen/unseen experiment (``abm experiment run seen_unseen``) cut to one task, with smaller views
    over a tighter workspace cube, AdamW at 1e-3 and enough steps for the ~2 cm a grasp needs.

    Attributes:
        out: output folder (data, one folder per method, eval, logs and report inside).
        tasks: trainable tasks to use.
        methods: policy variants to train and compare.
        episodes: demonstrations per task (seen objects).
        steps: training steps per method.
        batch: training batch size.
        optimizer: adamw (learns fastest in a short CPU run) or lamb (the paper's).
        lr: peak learning rate.
        warmup: linear warm-up steps.
        policy: the network of every method (the small preset with the recipe's ``policy:`` changes, the policy
            flags' and ``--set KEY=VALUE``'s; each method trains these changes of its own small preset).
        eval_episodes: evaluation episodes per task and split.
        max_steps: keyframes per evaluation episode.
        workers: parallel processes for data generation and evaluation.
        resolution: camera image side (pixels) of demonstrations and evaluation.
        device: torch device (cpu, cuda).
        clip_model: CLIP weights (hub name or local folder) for the grounder (default: the best found, see
            ``choose_grounder``: pretrained CLIP, else the benchmark CLIP, else the oracle; 'tiny' and
            'random:ARCH' are random weights, for tests only).
        offline: never try to download CLIP weights from the model hub.
        seed: seed of the demonstrations.
    """

    out: Path = field(default_factory=lambda: Path(spec().out))
    tasks: list[str] = field(default_factory=lambda: list(spec().data.tasks))
    methods: list[str] = field(default_factory=lambda: [run.method for run in spec().runs.values()],
                               metadata={"choices": VARIANTS.names})  # refused when parsed, before any work
    episodes: int = field(default_factory=lambda: spec().data.episodes)
    steps: int = field(default_factory=lambda: recipe()["steps"])
    batch: int = field(default_factory=lambda: recipe()["batch"])
    optimizer: str = field(default_factory=lambda: recipe()["optimizer"], metadata={"choices": ["adamw", "lamb"]})
    lr: float = field(default_factory=lambda: recipe()["lr"])
    warmup: int = field(default_factory=lambda: recipe()["warmup"])
    policy: PolicyConfig = field(default_factory=lambda: preset_policy("small", "abm", recipe()["policy"]),
                                 metadata={"cli": False})
    eval_episodes: int = field(default_factory=lambda: spec().evaluation.episodes)
    max_steps: int = field(default_factory=lambda: spec().evaluation.max_steps)
    workers: int = field(default_factory=lambda: spec().evaluation.workers)
    resolution: int = field(default=CAMERA_RESOLUTION, metadata={"flag": "--camera-resolution"})
    device: str = "cpu"
    clip_model: str | None = None
    offline: bool = False
    seed: int = 0


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "quickstart",
        help="generate data, train abm and rvt, evaluate on seen/unseen objects, write a report",
        description="\n\n".join(textwrap.fill(" ".join(part.split()), 79) for part in (
            __doc__.split("\n\n")[0], f"With the defaults: {quickstart_text()}.")),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_config_arguments(p, QuickstartConfig)
    p.add_argument("--set", dest="overrides", type=parse_override, action="append", default=[], metavar="KEY=VALUE",
                   help="change a policy config field (repeatable; same as the policy flags below)")
    add_config_arguments(p, PolicyConfig, overrides_only=True, exclude=("variant", "preset", "extra"),
                         dest_prefix=POLICY_DEST, title="policy (overrides of the small preset; quickstart "
                         "defaults: the 'policy' of configs/quickstart.yaml)")

    p.set_defaults(func="abm.cli.commands.quickstart:run")
