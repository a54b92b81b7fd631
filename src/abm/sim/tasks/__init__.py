"""ABM-Bench tasks: importing this package registers every built-in task in :data:`TASKS`."""

from abm.sim.tasks import (  # noqa: F401  (registration)
    close_jar,
    compositional,
    insert_peg,
    pick_block,
    place_food,
    place_wine,
    put_in_container,
    put_in_shelf,
    take_off_pan,
    water_plants,
)
from abm.sim.tasks.base import TASKS, Task, TaskInstance, register_task


def get_task(name: str, splits=None) -> Task:
    """An instance of a registered task (``splits``: :class:`abm.sim.splits.ObjectSplits` or ``None``)."""
    try:
        cls = TASKS[name]
    except KeyError:
        raise KeyError(f"unknown task {name!r}; known tasks: {sorted(TASKS)}") from None
    return cls(splits)


__all__ = ["TASKS", "Task", "TaskInstance", "get_task", "register_task"]
