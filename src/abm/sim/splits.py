"""Seen / unseen object splits, read from a YAML data file.

The default file ships with the package (``abm/sim/splits.yaml``); a user can point at another file to
define other held-out sets without code changes. Format::

    version: 1
    tasks:
      <task name>:
        <split name>: [<canonical object name>, ...]

A malformed file, an unknown task, split or object raises :class:`SplitFileError` naming the file and
the problem.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from abm.sim.catalog import CATALOG
from abm.types import SPLITS

DEFAULT_SPLITS_PATH = Path(__file__).with_name("splits.yaml")
SPLITS_VERSION = 1


class SplitFileError(ValueError):
    """A split file that cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class ObjectSplits:
    """Task -> split -> list of canonical object names.

    Attributes:
        tasks: the parsed mapping.
        path: where it came from.
    """

    tasks: dict[str, dict[str, list[str]]]
    path: Path

    def objects(self, task: str, split: str) -> list[str]:
        """Objects of one task and split, with a clear error if either is missing."""
        if task not in self.tasks:
            raise SplitFileError(f"{self.path}: no entry for task {task!r} (has {sorted(self.tasks)})")
        if split not in self.tasks[task]:
            raise SplitFileError(f"{self.path}: task {task!r} has no split {split!r} "
                                 f"(has {sorted(self.tasks[task])})")
        return list(self.tasks[task][split])


def load_splits(path: str | Path | None = None) -> ObjectSplits:
    """Read and validate a split file (default: the packaged ``splits.yaml``)."""
    path = Path(path) if path is not None else DEFAULT_SPLITS_PATH
    if not path.is_file():
        raise SplitFileError(f"{path}: split file not found")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise SplitFileError(f"{path}: not valid YAML ({err})") from None
    if not isinstance(raw, dict):
        raise SplitFileError(f"{path}: expected a mapping with keys 'version' and 'tasks'")
    if raw.get("version") != SPLITS_VERSION:
        raise SplitFileError(f"{path}: 'version' must be {SPLITS_VERSION}, got {raw.get('version')!r}")
    tasks = raw.get("tasks")
    if not isinstance(tasks, dict) or not tasks:
        raise SplitFileError(f"{path}: 'tasks' must be a non-empty mapping of task -> split -> objects")
    from abm.sim.tasks import TASKS

    out: dict[str, dict[str, list[str]]] = {}
    for task, splits in tasks.items():
        if task not in TASKS:
            raise SplitFileError(f"{path}: unknown task {task!r}; known tasks: {sorted(TASKS)}")
        if not isinstance(splits, dict) or not splits:
            raise SplitFileError(f"{path}: task {task!r} must map split names to object lists")
        out[task] = {}
        for split, names in splits.items():
            if split not in SPLITS:
                raise SplitFileError(f"{path}: task {task!r} has unknown split {split!r}; use one of {SPLITS}")
            if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
                raise SplitFileError(f"{path}: {task}/{split} must be a non-empty list of object names")
            unknown = [n for n in names if n not in CATALOG]
            if unknown:
                raise SplitFileError(f"{path}: {task}/{split} names unknown objects {unknown}; "
                                     f"known objects: {sorted(CATALOG)}")
            problem = TASKS[task].check_objects(names)
            if problem:
                raise SplitFileError(f"{path}: {task}/{split}: {problem}")
            out[task][split] = list(names)
        both = sorted(set(out[task].get("seen", [])) & set(out[task].get("unseen", [])))
        if both:
            raise SplitFileError(f"{path}: {task}: {both} listed as both seen and unseen; an unseen object "
                                 "must never appear in training")
    return ObjectSplits(out, path)
