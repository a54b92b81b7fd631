"""Class vocabulary and caption templates for training the benchmark CLIP (``abm clip train``).

Every image the renderer (:mod:`abm.clip_training.data`) produces is labelled with *classes*: one per
catalog object (:data:`abm.sim.catalog.CATALOG`, seen, unseen and compositional objects alike — an
internet-scale CLIP would have seen all of them) plus three background classes (the table, the floor /
everything behind it, the robot arm). Captions are drawn from templates over the name, its colour and
its category ("a photo of a red block", "a ketchup", "a photo of a ketchup, a type of grocery item").

The generic phrases the mask field contrasts against (:data:`abm.grounding.mask_field.DEFAULT_NEGATIVES`:
"object", "things", "stuff", "texture") get a meaning the way web captions would give it: the table is
also captioned "a photo of a texture", the floor "a photo of stuff", the robot "a photo of things", and
the dense (per-patch) loss of :mod:`abm.clip_training.train` makes "an object" the second-best phrase of
every object patch (see :data:`GENERIC_PARENT`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from abm.language.instruction import clip_prompt
from abm.sim.catalog import BLOCK_COLOURS, CATALOG

TABLE, FLOOR, ROBOT = "table", "floor", "robot arm"
BACKGROUND_CLASSES: tuple[str, ...] = (TABLE, FLOOR, ROBOT)
IGNORE = 255
"""Segmentation value of pixels without a class (never produced by the renderer; reserved)."""

GENERIC_PARENT: dict[str, str] = {TABLE: "texture", FLOOR: "stuff", ROBOT: "things"}
"""Background class -> the generic negative phrase that describes it; every object's parent is "object"."""
OBJECT_PARENT = "object"

CATEGORY_WORDS: dict[str, str] = {
    "grocery": "grocery item", "block": "cube", "bottle": "bottle", "container": "dish", "target": "target pad",
    "rack": "wine rack", "shelf": "shelf", "mug": "cup", "plant": "potted plant", "jar": "jar", "lid": "lid",
    "peg": "peg", "ring": "ring", "frypan": "pan",
}

OBJECT_TEMPLATES: tuple[str, ...] = (
    "{prompt}", "{prompt}", "{a} {x}", "the {x}", "a photo of the {x}", "{a} {x} on a table",
    "a close-up photo of {a} {x}", "a rendering of {a} {x}", "a picture of {a} {x}", "{prompt}, a type of {cat}",
)
COLOUR_TEMPLATES: tuple[str, ...] = ("{a} {colour} {cat}", "a photo of {a} {colour} {cat}", "a {cat} that is {colour}")
BACKGROUND_CAPTIONS: dict[str, tuple[str, ...]] = {
    TABLE: ("a photo of a table", "a table top", "a photo of a texture", "an empty table", "a texture"),
    FLOOR: ("a photo of the floor", "a photo of stuff", "a dark floor", "stuff", "the background"),
    ROBOT: ("a photo of a robot arm", "a robot gripper", "a photo of things", "a robot", "things"),
}


def article(word: str) -> str:
    """``"an"`` before a vowel letter, else ``"a"``."""
    return "an" if word[:1].lower() in "aeiou" else "a"


def class_names(object_names: Sequence[str] | None = None) -> tuple[str, ...]:
    """The class list: object names (default: the whole catalog, in catalog order), then the background."""
    if object_names is None:
        object_names = list(CATALOG)
    return (*object_names, *BACKGROUND_CLASSES)


def class_prompts(classes: Sequence[str]) -> list[str]:
    """The mask-field prompt ``"a photo of a X"`` of every class (what the grounder asks at run time)."""
    return [clip_prompt(c) for c in classes]


def _colour_and_category(name: str) -> tuple[str | None, str]:
    """(colour word of a coloured primitive or None, category word) of an object name."""
    entry = CATALOG.get(name)
    category = entry.category if entry is not None else "object"
    first = name.split()[0]
    colour = first if first in BLOCK_COLOURS and category in ("block", "jar", "peg") else None
    return colour, CATEGORY_WORDS.get(category, category)


def caption(name: str, rng: np.random.Generator) -> str:
    """One random caption of class ``name`` (object or background class)."""
    if name in BACKGROUND_CAPTIONS:
        options = BACKGROUND_CAPTIONS[name]
        return options[int(rng.integers(len(options)))]
    colour, cat = _colour_and_category(name)
    templates = OBJECT_TEMPLATES + (COLOUR_TEMPLATES if colour else ())
    template = templates[int(rng.integers(len(templates)))]
    return template.format(prompt=clip_prompt(name), a=article(colour or name), x=name, colour=colour, cat=cat)
