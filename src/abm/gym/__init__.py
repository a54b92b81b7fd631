"""Gymnasium environments for every ABM-Bench task and split, registered on import.

Ids are ``abm/<task>-<split>-v0`` (``abm/pick_block-seen-v0``, ``abm/put_in_container-compositional-v0``, ...):
one per task and split of the built-in split file (``abm tasks`` lists them; :data:`ENV_IDS` holds them)::

    import gymnasium
    import abm.gym  # registers the environments

    env = gymnasium.make("abm/pick_block-seen-v0", resolution=128)  # 25 keyframes an episode, render_mode None
    obs, info = env.reset(seed=0)              # the benchmark's scene of seed 0
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Observation: the four RGB-D cameras with their calibration and segmentation, the gripper state and the
instruction (a Text space); action: one keyframe (position in metres, quaternion x y z w, gripper open,
ignore collision) as a Dict space. :mod:`abm.gym.env` documents both, the reward and the seeds;
``examples/gym_zoo_policy.py`` runs a zoo policy in one. Needs the ``gym`` extra (``pip install 'abm[gym]'``)
and the simulator (``sim``).
"""

from __future__ import annotations

try:
    import gymnasium
except ImportError as err:  # pragma: no cover - depends on the installed extras
    raise ImportError("abm.gym needs gymnasium: pip install 'abm[gym]' (scripts/bootstrap.sh installs it)") from err

from abm.gym.env import (
    AbmTaskEnv,
    action_space,
    check_action,
    from_action,
    from_observation,
    observation_space,
    to_action,
    to_observation,
)
from abm.sim.env import DEFAULT_MAX_STEPS
from abm.sim.splits import load_splits

ENTRY_POINT = "abm.gym.env:AbmTaskEnv"
ENV_VERSION = 0


def env_id(task: str, split: str) -> str:
    """The registered id of a task and split: ``abm/<task>-<split>-v0``."""
    return f"abm/{task}-{split}-v{ENV_VERSION}"


def register_envs() -> tuple[str, ...]:
    """Register one environment per task and split of the built-in split file (again: nothing new); their ids.

    Each spec's ``max_episode_steps`` is :data:`~abm.sim.env.DEFAULT_MAX_STEPS` (25 keyframes, the benchmark's budget),
    so ``gymnasium.make`` truncates there; the env itself does not truncate unless given ``max_steps``."""
    ids = []
    for task, splits in load_splits(None).tasks.items():
        for split in splits:
            name = env_id(task, split)
            if name not in gymnasium.registry:
                gymnasium.register(id=name, entry_point=ENTRY_POINT, kwargs={"task": task, "split": split},
                                   max_episode_steps=DEFAULT_MAX_STEPS)
            ids.append(name)
    return tuple(ids)


ENV_IDS: tuple[str, ...] = register_envs()
"""Every registered id, in the split file's order."""

__all__ = ["ENV_IDS", "AbmTaskEnv", "action_space", "check_action", "env_id", "from_action", "from_observation",
           "observation_space", "register_envs", "to_action", "to_observation"]
