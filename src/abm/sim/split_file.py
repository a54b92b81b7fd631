"""The split file's format and checks (:class:`ObjectSplits`, :func:`read_splits`), below the tasks: it gets
the task classes it validates against as an argument, so the tasks can read their default splits without
importing :mod:`abm.sim.splits` (which imports the tasks for :func:`~abm.sim.splits.load_splits`). The file
format is described in :mod:`abm.sim.splits`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from abm.configuration import SPLITS
from abm.errors import ConfigError
from abm.files import load_yaml
from abm.sim.catalog import CATALOG

if TYPE_CHECKING:
    from abm.sim.tasks.base import Task

DEFAULT_SPLITS_PATH = Path(__file__).with_name("splits.yaml")
SPLITS_VERSION = 1


class SplitFileError(ConfigError):
    """A split file that cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class ObjectSplits:
    """Task -> split -> list of canonical object names.

    Attributes:
        tasks: the parsed mapping of every task's first slot (its target objects X).
        path: where it came from.
        slots: task -> slot name (e.g. ``"containers"``) -> split -> objects, for the tasks that declare a
            second slot (:attr:`abm.sim.tasks.base.Task.slots`); empty for every other task.
    """

    tasks: dict[str, dict[str, list[str]]]
    path: Path
    slots: dict[str, dict[str, dict[str, list[str]]]] = field(default_factory=dict)

    def objects(self, task: str, split: str) -> list[str]:
        """Objects of one task and split, with a clear error if either is missing."""
        if task not in self.tasks:
            raise SplitFileError(f"{self.path}: no entry for task {task!r} (has {sorted(self.tasks)})")
        if split not in self.tasks[task]:
            raise SplitFileError(f"{self.path}: task {task!r} has no split {split!r} "
                                 f"(has {sorted(self.tasks[task])})")
        return list(self.tasks[task][split])

    def slot_objects(self, task: str, slot: str, split: str) -> list[str]:
        """Objects of a task's second slot (e.g. ``"containers"``) in one split, with a clear error if missing."""
        lists = self.slots.get(task, {}).get(slot)
        if lists is None:
            raise SplitFileError(f"{self.path}: task {task!r} has no {slot!r} lists")
        if split not in lists:
            raise SplitFileError(f"{self.path}: task {task!r} has no {slot}/{split} list (has {sorted(lists)})")
        return list(lists[split])


def read_splits(path: str | Path | None, registry: Mapping[str, type[Task]]) -> ObjectSplits:
    """Read a split file (``None``: the packaged ``splits.yaml``) and validate it against the task classes in
    ``registry`` (name -> class; :func:`abm.sim.splits.load_splits` passes every registered task)."""
    path = Path(path) if path is not None else DEFAULT_SPLITS_PATH
    if not path.is_file():
        raise SplitFileError(f"{path}: split file not found")
    try:
        raw = load_yaml(path, "split file")
    except ValueError as err:
        raise SplitFileError(str(err)) from None
    if not isinstance(raw, dict):
        raise SplitFileError(f"{path}: expected a mapping with keys 'version' and 'tasks'")
    unknown = sorted(str(k) for k in raw if k not in ("version", "tasks"))
    if unknown:
        raise SplitFileError(f"{path}: unknown keys {unknown} (expected: ['tasks', 'version'])")
    if raw.get("version") != SPLITS_VERSION:
        raise SplitFileError(f"{path}: 'version' must be {SPLITS_VERSION}, got {raw.get('version')!r}")
    tasks = raw.get("tasks")
    if not isinstance(tasks, dict) or not tasks:
        raise SplitFileError(f"{path}: 'tasks' must be a non-empty mapping of task -> split -> objects")
    out: dict[str, dict[str, list[str]]] = {}
    slots: dict[str, dict[str, dict[str, list[str]]]] = {}
    for task, splits in tasks.items():
        if task not in registry:
            raise SplitFileError(f"{path}: unknown task {task!r}; known tasks: {sorted(registry)}")
        if not isinstance(splits, dict) or not splits:
            raise SplitFileError(f"{path}: task {task!r} must map split names to object lists")
        declared = registry[task].slots
        out[task] = {}
        for split, names in splits.items():
            if split in declared:
                slots.setdefault(task, {})[split] = _slot_lists(path, task, split, names, declared[split])
                continue
            if split not in SPLITS:
                extra = f" or its object slots {sorted(declared)}" if declared else ""
                raise SplitFileError(f"{path}: task {task!r} has unknown split {split!r}; use one of {SPLITS}{extra}")
            out[task][split] = _object_list(path, f"{task}/{split}", names)
            problem = registry[task].check_objects(names)
            if problem:
                raise SplitFileError(f"{path}: {task}/{split}: {problem}")
        if not out[task]:
            raise SplitFileError(f"{path}: task {task!r} lists no split of its target objects")
        _check_disjoint(path, task, out[task])
        for slot in declared:
            have = sorted(slots.get(task, {}).get(slot, {}))
            if have != sorted(out[task]):
                raise SplitFileError(f"{path}: task {task!r} needs {slot!r} lists for exactly its splits "
                                     f"{sorted(out[task])} (has {have})")
    result = ObjectSplits(out, path, slots)
    for task in out:
        problem = registry[task].check_splits(result)
        if problem:
            raise SplitFileError(f"{path}: {task}: {problem}")
    return result


def _object_list(path: Path, where: str, names: object) -> list[str]:
    """``names`` as a list of known canonical object names, else a :class:`SplitFileError` about ``where``."""
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise SplitFileError(f"{path}: {where} must be a non-empty list of object names")
    unknown = [n for n in names if n not in CATALOG]
    if unknown:
        raise SplitFileError(f"{path}: {where} names unknown objects {unknown}; known objects: {sorted(CATALOG)}")
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise SplitFileError(f"{path}: {where} lists {repeated} more than once; list each object once")
    return list(names)


def _slot_lists(path: Path, task: str, slot: str, lists: object, categories: tuple[str, ...]) -> dict[str, list[str]]:
    """The ``split -> objects`` mapping of a task's second slot, checked like the first slot's lists."""
    if not isinstance(lists, dict) or not lists:
        raise SplitFileError(f"{path}: {task}/{slot} must map split names to object lists")
    out: dict[str, list[str]] = {}
    for split, names in lists.items():
        if split not in SPLITS:
            raise SplitFileError(f"{path}: {task}/{slot} has unknown split {split!r}; use one of {SPLITS}")
        out[split] = _object_list(path, f"{task}/{slot}/{split}", names)
        bad = [n for n in names if CATALOG[n].category not in categories]
        if bad:
            raise SplitFileError(f"{path}: {task}/{slot}/{split}: objects {bad} are not of the categories "
                                 f"this slot uses ({list(categories)})")
    _check_disjoint(path, f"{task}/{slot}", out)
    return out


def _check_disjoint(path: Path, where: str, lists: dict[str, list[str]]) -> None:
    both = sorted(set(lists.get("seen", [])) & set(lists.get("unseen", [])))
    if both:
        raise SplitFileError(f"{path}: {where}: {both} listed as both seen and unseen; an unseen object "
                             "must never appear in training")
