"""Training throughput of a policy preset (samples/s), data pipeline included.

Trains on built-in synthetic episodes (4 cameras, 128^2 by default) with the real data pipeline
(fusion, oracle grounding, SE(3) augmentation, rendering) and the real optimiser (LAMB), and reports
samples/s over the timed steps plus the share of time spent waiting for data.

    python benchmarks/train_speed.py --preset small --method abm --batch 8 --steps 10
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from abm.data.keyframes import KeyframeDataset, StepSampler, collate, worker_init
from abm.machine import describe_machine
from abm.policy import MultiViewTransformer, PolicyConfig, policy_loss, translation_targets
from abm.policy.language import HashLanguageEncoder
from abm.render import OrthographicRenderer
from abm.train.synthetic import synthetic_episodes


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="small", choices=["small", "paper"])
    p.add_argument("--method", default="abm")
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--steps", type=int, default=10, help="timed steps")
    p.add_argument("--warmup", type=int, default=2, help="untimed steps")
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--episodes", type=int, default=8)
    p.add_argument("--camera-resolution", type=int, default=128)
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = default)")
    args = p.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    from torch_optimizer import Lamb

    device = torch.device(args.device)
    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset(args.preset, args.method)
    episodes = synthetic_episodes(args.episodes, args.camera_resolution)
    ds = KeyframeDataset(episodes, cfg, HashLanguageEncoder(cfg.lang_dim))
    total = args.warmup + args.steps
    loader = torch.utils.data.DataLoader(ds, batch_size=args.batch, sampler=StepSampler(len(ds), args.batch, total),
                                         num_workers=args.workers, collate_fn=collate, worker_init_fn=worker_init)
    model = MultiViewTransformer(cfg).to(device).train()
    opt = Lamb(model.parameters(), lr=1e-3)
    renderer = OrthographicRenderer(ds.workspace, cfg.resolution, cfg.views, device=device)
    amp = device.type == "cuda"
    data_s = step_s = 0.0
    t_prev = time.perf_counter()
    for i, batch in enumerate(loader):
        t_data = time.perf_counter()
        batch = {k: v.to(device) for k, v in batch.items()}
        with torch.autocast(device_type=device.type, dtype=torch.bfloat16, enabled=amp):
            out = model(batch["images"], batch["proprio"], batch["lang"], mask=batch.get("mask"),
                        ifd_features=batch.get("ifd_features"), ifd_index=batch.get("ifd_index"))
        loss = policy_loss(out, translation_targets(renderer, batch["position"]), batch["rotation_bins"],
                           batch["gripper"], batch["collision"]).total
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        if device.type == "cuda":
            torch.cuda.synchronize()
        t_end = time.perf_counter()
        if i >= args.warmup:
            data_s += t_data - t_prev
            step_s += t_end - t_data
        t_prev = t_end
    n = args.steps * args.batch
    result = {
        "preset": cfg.preset, "method": args.method, "device": str(device), "batch": args.batch,
        "steps": args.steps, "workers": args.workers, "threads": torch.get_num_threads(),
        "parameters": model.num_parameters(), "samples_per_s": n / (data_s + step_s),
        "s_per_step": (data_s + step_s) / args.steps, "data_share": data_s / (data_s + step_s),
        "machine": describe_machine(),
        "gpu": torch.cuda.get_device_name() if device.type == "cuda" else None,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
