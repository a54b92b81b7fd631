"""Inference latency of one keyframe step: fusion + grounding + render + policy forward + decoding.

Uses a randomly initialised policy (latency does not depend on the weights) and the built-in
synthetic scene (4 cameras). On CUDA the forward pass runs under bf16 autocast.

    python benchmarks/policy_speed.py --presets small paper --devices cpu cuda --repeats 5
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from abm.machine import describe_machine
from abm.policy import KeyframePolicy, PolicyConfig
from abm.policy.language import HashLanguageEncoder
from abm.train.synthetic import synthetic_episode


def measure(preset: str, method: str, device: str, repeats: int, camera_resolution: int) -> dict:
    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset(preset, method)
    policy = KeyframePolicy(cfg, HashLanguageEncoder(cfg.lang_dim), {"kind": "oracle"}).to(device).eval()
    ep = synthetic_episode(0, camera_resolution)
    obs, _ = ep.steps[0]
    policy.act(obs, ep.instruction, ep.object_names)  # warm-up (allocations, kernels)
    times, stages = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        policy.act(obs, ep.instruction, ep.object_names)
        times.append(time.perf_counter() - t)
        stages.append(dict(policy.last_timings))
    med = statistics.median(times)
    return {
        "preset": cfg.preset, "method": method, "device": device,
        "amp": "bf16" if device.startswith("cuda") else "fp32", "median_s": med, "fps": 1.0 / med,
        "stages_median_s": {k: statistics.median(s[k] for s in stages) for k in stages[0]},
        "parameters": policy.model.num_parameters(), "threads": torch.get_num_threads(),
        "machine": describe_machine(),
        "gpu": torch.cuda.get_device_name() if device.startswith("cuda") else None,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--presets", nargs="+", default=["small", "paper"])
    p.add_argument("--devices", nargs="+", default=["cpu"] + (["cuda"] if torch.cuda.is_available() else []))
    p.add_argument("--method", default="abm")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--camera-resolution", type=int, default=128)
    args = p.parse_args()
    for device in args.devices:
        if device.startswith("cuda") and not torch.cuda.is_available():
            print(json.dumps({"device": device, "skipped": "CUDA not available"}))
            continue
        for preset in args.presets:
            print(json.dumps(measure(preset, args.method, device, args.repeats, args.camera_resolution)), flush=True)


if __name__ == "__main__":
    main()
