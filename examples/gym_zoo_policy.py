"""Run a zoo policy for one episode in an abm.gym environment (gymnasium's reset / step loop).

The policy is the model zoo's ABM with the oracle mask (``models/abm_oracle.pt``); the environment is one
ABM-Bench task and split registered by ``import abm.gym`` (``abm/<task>-<split>-v0``). Each step the gym
observation goes back to an :class:`abm.types.Observation` (:func:`abm.gym.to_observation`), the policy predicts
the next keyframe, and the keyframe goes to ``env.step`` as the Dict action (:func:`abm.gym.from_action`).

Usage (from the repository root, with the ``gym`` and ``sim`` extras)::

    MUJOCO_GL=egl .venv/bin/python examples/gym_zoo_policy.py --task pick_block --split seen --seed 0
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium

import abm.gym  # noqa: F401  (registers the abm/... environments)
from abm.configuration import CAMERA_RESOLUTION
from abm.gym import from_action, to_observation
from abm.policy import KeyframePolicy

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", type=Path, default=ROOT / "models" / "abm_oracle.pt", help="zoo policy file")
    ap.add_argument("--task", default="pick_block", help="ABM-Bench task (abm tasks lists them)")
    ap.add_argument("--split", default="seen", help="seen, unseen or compositional")
    ap.add_argument("--seed", type=int, default=0, help="scene seed (the benchmark's)")
    ap.add_argument("--resolution", type=int, default=CAMERA_RESOLUTION, help="camera side in pixels")
    ap.add_argument("--max-steps", type=int, default=25, help="keyframes before the episode is truncated")
    args = ap.parse_args()

    policy = KeyframePolicy.from_checkpoint(args.checkpoint)
    env = gymnasium.make(f"abm/{args.task}-{args.split}-v0", resolution=args.resolution,
                         max_episode_steps=args.max_steps)  # gymnasium's TimeLimit (the spec's is 25)
    obs, info = env.reset(seed=args.seed)
    print(f"{env.spec.id if env.spec else args.task} seed {args.seed}: {obs['instruction']!r}; "
          f"objects: {', '.join(info['object_names'].values())}")
    policy.reset()
    total, step, start = 0.0, 0, time.perf_counter()
    while True:
        keyframe = policy.act(to_observation(obs, step), obs["instruction"], info["object_names"])
        obs, reward, terminated, truncated, info = env.step(from_action(keyframe))
        total += float(reward)
        step += 1
        print(f"step {step}: position {keyframe.position.round(3).tolist()} m, gripper "
              f"{'open' if keyframe.gripper_open else 'closed'} -> {info['motion']}, reward {reward}")
        if terminated or truncated:
            break
    env.close()
    result = "success" if terminated else "truncated (no success)"
    print(f"{result} after {step} keyframes, return {total}, {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
