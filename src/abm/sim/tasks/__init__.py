"""ABM-Bench tasks: importing this package imports every module in it, so each task a module registers (with
:func:`register_task`) is in :data:`TASKS`. Adding a task is adding its module here (and its objects to the split
file, :mod:`abm.sim.splits`); nothing lists the tasks by name.
"""

import importlib
import pkgutil

from abm.sim.split_file import ObjectSplits
from abm.sim.tasks.base import TASKS, Task, TaskInstance, register_task

for _module in pkgutil.iter_modules(__path__):  # alphabetical: the order tasks are registered in
    if _module.name != "base":
        importlib.import_module(f"{__name__}.{_module.name}")


def get_task(name: str, splits: ObjectSplits | None = None) -> Task:
    """An instance of a registered task (``splits``: :class:`abm.sim.splits.ObjectSplits` or ``None``).

    Raises:
        KeyError: an unknown task (:class:`abm.registry.UnknownNameError`, listing the known ones).
    """
    return TASKS[name](splits)


__all__ = ["TASKS", "Task", "TaskInstance", "get_task", "register_task"]
