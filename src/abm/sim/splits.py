"""Seen / unseen object splits, read from a YAML data file.

The default file ships with the package (``abm/sim/splits.yaml``); a user can point at another file to
define other held-out sets without code changes. Format::

    version: 1
    tasks:
      <task name>:
        <split name>: [<canonical object name>, ...]
        <slot name>:                     # only for a task that declares a second object slot
          <split name>: [<canonical object name>, ...]

The lists directly under a task are its first slot (the target X). A task whose instructions name a
second object (``put_in_container``: "put the X in the Y") declares that slot in
:attr:`abm.sim.tasks.base.Task.slots` (YAML key -> catalog categories, e.g. ``containers: (container,)``)
and lists its objects per split under that key; the slot must define the same splits as the first one.
Both slots get the same checks (known objects of the right categories, nothing both seen and unseen),
and a task may add its own checks of the whole file (:meth:`abm.sim.tasks.base.Task.check_splits`,
e.g. put_in_container's pairing rule). Split files without second slots read exactly as before.

A malformed file, an unknown task, split or object raises :class:`SplitFileError` naming the file and
the problem.
"""

from __future__ import annotations

import copy
from pathlib import Path

from abm.sim.split_file import DEFAULT_SPLITS_PATH, SPLITS_VERSION, ObjectSplits, SplitFileError, read_splits
from abm.sim.tasks import TASKS

__all__ = ["DEFAULT_SPLITS_PATH", "SPLITS_VERSION", "ObjectSplits", "SplitFileError", "load_splits", "read_splits"]


_READ: dict[tuple[str, int, int, tuple[str, ...]], ObjectSplits] = {}
"""Split files read by this process, per (path, modification time, size, registered tasks)."""


def load_splits(path: str | Path | None = None) -> ObjectSplits:
    """Read and validate a split file (default: the packaged ``splits.yaml``) against every registered task.

    A file is parsed once per process and version (an episode's environment reads it: parsing the YAML cost
    ~0.1 CPU s per episode); each call returns a copy of what was read."""
    file = Path(path) if path is not None else DEFAULT_SPLITS_PATH
    try:
        stat = file.stat()
    except OSError:
        return read_splits(path, TASKS)  # the reader names the problem
    key = (str(file.resolve()), stat.st_mtime_ns, stat.st_size, tuple(TASKS))
    if key not in _READ:
        _READ[key] = read_splits(path, TASKS)
    return copy.deepcopy(_READ[key])
