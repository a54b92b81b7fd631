"""Training throughput of a policy preset (samples/s), data pipeline included, and where the time goes.

Trains on built-in synthetic episodes (4 cameras, 128^2 by default) with the real data pipeline
(fusion, oracle grounding, SE(3) augmentation, rendering) and the real optimiser, and reports
samples/s over the timed steps plus the seconds per step spent in each stage: data (fuse, ground,
augment), forward (``KeyframePolicy.compute_loss``: rendering on the policy's device, model and loss),
backward and optimiser. ``render_s_per_step`` is the rendering part of forward, timed separately.

    python benchmarks/train_speed.py --preset small --method abm --batch 8 --steps 10
    OMP_NUM_THREADS=1 python benchmarks/train_speed.py --threads 1 --set resolution=64 --set patch_size=8
    OMP_NUM_THREADS=1 python benchmarks/train_speed.py --threads 1 --set resolution=64 --set patch_size=8 --compile

``cpu_s_per_step`` (process CPU time per timed step, including the timed rendering pass) stays meaningful on a
shared machine where wall-clock ``s_per_step`` does not; with one thread it is the step's compute time.

Side by side with another commit (``--against REF``): the same benchmark runs at the same time from a temporary
``git worktree`` of REF and from this tree, one process each (use ``--threads 1``), so both see the same machine;
the ratio of samples/s is printed and ``--record FILE`` appends both rows to a JSON list
(``docs/results/train_speed.json``: commit, config, threads, samples_per_s, forward_s, backward_s)::

    python benchmarks/train_speed.py --threads 1 --optimizer adamw --set resolution=64 --set patch_size=8 \
        --steps 20 --against ecf079f --record docs/results/train_speed.json

``--compile-current`` compiles this tree's network only (the baseline runs eager, as a commit from before
``--compile`` must).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import torch

from abm.cli.train import parse_override
from abm.data.keyframes import KeyframeDataset, StepSampler, collate, worker_init
from abm.machine import describe_machine
from abm.policy import KeyframePolicy, PolicyConfig
from abm.policy.language import HashLanguageEncoder
from abm.train.loop import make_optimizer
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
    p.add_argument("--optimizer", default="lamb", choices=["lamb", "adamw"])
    p.add_argument("--set", dest="overrides", type=parse_override, action="append", default=[], metavar="KEY=VALUE",
                   help="override a policy config field, e.g. --set resolution=64 (repeatable)")
    p.add_argument("--compile", action="store_true", help="run the network through torch.compile (compile time "
                   "falls in the untimed warm-up steps and is reported as compile_s)")
    p.add_argument("--bf16", default="off", choices=["auto", "on", "off"], help="bf16 autocast on CPU (default off)")
    p.add_argument("--profile", type=int, default=0, metavar="ROWS", help="after the timed steps, profile 3 more "
                   "steps with torch.profiler and print the ROWS operators with the most self CPU time")
    p.add_argument("--against", default=None, metavar="REF", help="also run the benchmark from a git worktree of REF, "
                   "at the same time, and compare")
    p.add_argument("--compile-current", action="store_true", help="with --against: compile this tree's network "
                   "only (the baseline runs eager, e.g. a commit from before --compile)")
    p.add_argument("--record", type=Path, default=None, metavar="FILE", help="with --against: append both rows to "
                   "this JSON list")
    args = p.parse_args()
    if args.against:
        compare(args)
        return
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    torch.manual_seed(0)
    cfg = PolicyConfig.from_preset(args.preset, args.method, **dict(args.overrides))
    episodes = synthetic_episodes(args.episodes, args.camera_resolution)
    policy = KeyframePolicy(cfg, HashLanguageEncoder(cfg.lang_dim)).to(device).train()
    policy.use_cpu_bf16(args.bf16)
    policy.compile_network(args.compile)
    ds = KeyframeDataset(episodes, policy.workspace, **policy.sample_options())
    total = args.warmup + args.steps
    loader = torch.utils.data.DataLoader(ds, batch_size=args.batch, sampler=StepSampler(len(ds), args.batch, total),
                                         num_workers=args.workers, collate_fn=collate, worker_init_fn=worker_init)
    opt = make_optimizer(args.optimizer, policy.parameters(), lr=1e-3, weight_decay=0.0)
    render_s = 0.0
    stage: dict[str, float] = defaultdict(float)

    def sync() -> float:
        if device.type == "cuda":
            torch.cuda.synchronize()
        return time.perf_counter()

    warmup_s, cpu_start = 0.0, time.process_time()
    t_prev = time.perf_counter()
    for i, batch in enumerate(loader):
        t_data = time.perf_counter()
        loss, _ = policy.compute_loss(batch)
        t_fwd = sync()
        opt.zero_grad()
        loss.backward()
        t_bwd = sync()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
        opt.step()
        t_end = sync()
        if i == args.warmup - 1:
            cpu_start = time.process_time()
        if i >= args.warmup:
            with torch.no_grad():  # the rendering share of forward, timed on its own
                t_r = sync()
                policy.model_inputs(batch)
                render_s += sync() - t_r
            for name, dt in (("data", t_data - t_prev), ("forward", t_fwd - t_data), ("backward", t_bwd - t_fwd),
                             ("optimizer", t_end - t_bwd)):
                stage[name] += dt
        else:
            warmup_s += t_end - t_prev
        t_prev = time.perf_counter()
    cpu_s = time.process_time() - cpu_start  # CPU time of the timed steps: robust to a shared machine
    total_s = sum(stage.values())
    data_s = stage["data"]
    n = args.steps * args.batch
    result = {
        "preset": cfg.preset, "method": args.method, "device": str(device), "batch": args.batch,
        "steps": args.steps, "workers": args.workers, "threads": torch.get_num_threads(),
        "parameters": sum(p.numel() for p in policy.parameters()), "samples_per_s": n / total_s,
        "s_per_step": total_s / args.steps, "data_share": data_s / total_s,
        "stage_s_per_step": {k: round(v / args.steps, 4) for k, v in stage.items()},
        "render_s_per_step": round(render_s / args.steps, 4),
        "cpu_s_per_step": round(cpu_s / args.steps, 4), "warmup_s": round(warmup_s, 2),
        "compile": args.compile, "cpu_bf16": policy.cpu_bf16,
        "resolution": cfg.resolution, "patch_size": cfg.patch_size, "optimizer": args.optimizer,
        "machine": describe_machine(),
        "gpu": torch.cuda.get_device_name() if device.type == "cuda" else None,
    }
    if args.profile:
        from torch.profiler import ProfilerActivity, profile

        batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=args.batch, collate_fn=collate)))
        with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
            for _ in range(3):
                loss, _ = policy.compute_loss(batch)
                opt.zero_grad()
                loss.backward()
                opt.step()
        print(prof.key_averages(group_by_input_shape=True).table(sort_by="self_cpu_time_total",
                                                                 row_limit=args.profile, max_name_column_width=40))
    print(json.dumps(result))


def _commit(tree: Path, ref: str = "HEAD") -> str:
    out = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", ref], capture_output=True, text=True,
                         check=True)
    return out.stdout.strip()


def compare(args: argparse.Namespace) -> None:
    """Run this benchmark from this tree and from a worktree of ``args.against`` at the same time; print both
    and the speed-up, and append them to ``args.record``."""
    here = Path(__file__).resolve().parents[1]
    argv = [a for a in sys.argv[1:]]
    i = argv.index("--against")
    del argv[i:i + 2]
    if "--record" in argv:
        i = argv.index("--record")
        del argv[i:i + 2]
    compile_current = "--compile-current" in argv
    if compile_current:
        argv.remove("--compile-current")
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "baseline"
        subprocess.run(["git", "-C", str(here), "worktree", "add", "--detach", "-q", str(tree), args.against],
                       check=True)
        try:
            trees = {"baseline": tree, "current": here}
            procs = {}
            for name, root in trees.items():
                env = {**os.environ, "PYTHONPATH": str(root / "src"), "OMP_NUM_THREADS": str(args.threads or 1)}
                # this tree's script in both: the measurement is the same, only the library differs
                extra = ["--compile"] if compile_current and name == "current" else []
                procs[name] = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), *argv, *extra],
                                               env=env, stdout=subprocess.PIPE, text=True)
            results = {}
            for name, proc in procs.items():
                out, _ = proc.communicate()
                if proc.returncode:
                    raise SystemExit(f"the {name} benchmark failed (exit {proc.returncode})")
                results[name] = json.loads(out.strip().splitlines()[-1])
            commits = {"baseline": _commit(here, args.against), "current": _commit(here)}
        finally:
            subprocess.run(["git", "-C", str(here), "worktree", "remove", "--force", str(tree)], check=False)
    rows = []
    for name, r in results.items():
        config = " ".join(argv + (["--compile"] if compile_current and name == "current" else []))
        stage = r["stage_s_per_step"]
        rows.append({"commit": commits[name] + ("+" if name == "current" and _dirty(here) else ""), "config": config,
                     "threads": r["threads"], "samples_per_s": round(r["samples_per_s"], 3),
                     "forward_s": round(stage["forward"] - r["render_s_per_step"], 4),
                     "render_s": r["render_s_per_step"], "data_s": stage["data"],
                     "backward_s": stage["backward"], "cpu_s_per_step": r["cpu_s_per_step"], "machine": r["machine"]})
        print(json.dumps(rows[-1]))
    speedup = results["current"]["samples_per_s"] / results["baseline"]["samples_per_s"]
    cpu = results["baseline"]["cpu_s_per_step"] / results["current"]["cpu_s_per_step"]
    print(f"speed-up {commits['baseline']} -> {commits['current']}: {speedup:.2f}x samples/s "
          f"({cpu:.2f}x CPU s per step)")
    if args.record is not None:
        old = json.loads(args.record.read_text()) if args.record.exists() else []
        args.record.parent.mkdir(parents=True, exist_ok=True)
        args.record.write_text(json.dumps(old + rows, indent=1) + "\n")


def _dirty(tree: Path) -> bool:
    """Whether the tree's library has uncommitted changes (the row's commit then gets a ``+``)."""
    out = subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "src"], capture_output=True, text=True)
    return bool(out.stdout.strip())


if __name__ == "__main__":
    main()
