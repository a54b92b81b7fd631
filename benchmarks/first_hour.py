"""Record what a new user's first hour costs into src/abm/configs/measured.json (:mod:`abm.measured`) and rewrite
the blocks that read it (the README's first-hour block, docs/evaluation.md's quickstart block).

Each section is recorded from measured runs; sections not given keep their recorded values:

    # the quickstart on a fresh clone (QS, a folder outside the checkout), timed
    git clone . QS && cd QS && /usr/bin/time -v -o qs-time.txt abm quickstart && cd -
    python benchmarks/first_hour.py --quickstart QS/out/quickstart --quickstart-time QS/qs-time.txt \
        --quickstart-load "nothing else ran"
    # abm zoo eval with the default kernels and with AVX-512 switched off (another CPU type's kernels)
    abm zoo eval --out out/zoo
    ATEN_CPU_CAPABILITY=avx2 ONEDNN_MAX_CPU_ISA=AVX2 MKL_ENABLE_INSTRUCTIONS=AVX2 abm zoo eval --out out/zoo-avx2
    python benchmarks/first_hour.py --zoo-eval out/zoo --zoo-eval-minutes 6.5 --cross-cpu out/zoo-avx2
    # abm --help (timed here) and the test script (minutes from its own run)
    python benchmarks/first_hour.py --help-time --tests 8.5 14
    # the README's speed table: runs its benchmark commands here, one after another (~10 min on 2 cores)
    python benchmarks/first_hour.py --speed

The machine is this one's (its CPU model and core count) unless ``--machine`` names it.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import statistics
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
FILE = ROOT / "src" / "abm" / "configs" / "measured.json"
AVX2 = ("the AVX-512 kernels switched off (ATEN_CPU_CAPABILITY=avx2, ONEDNN_MAX_CPU_ISA=AVX2, "
        "MKL_ENABLE_INSTRUCTIONS=AVX2)")


def this_machine() -> str:
    """``CPU MODEL, N cores`` of this machine (``/proc/cpuinfo``)."""
    try:
        info = Path("/proc/cpuinfo").read_text()
        model = re.search(r"model name\s*:\s*(.+)", info)
        name = " ".join(model.group(1).split()) if model else "x86-64 CPU"
    except OSError:
        name = "x86-64 CPU"
    return f"{name}, {os.cpu_count()} cores"


def commit(folder: Path) -> str:
    """The short commit of the checkout ``folder`` lies in (a fresh clone's output folder), else of this one."""
    for where in (folder, ROOT):
        done = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=where, capture_output=True, text=True)
        if done.returncode == 0:
            return done.stdout.strip()
    raise SystemExit(f"first_hour: neither {folder} nor {ROOT} is in a git checkout")


def outcomes(folder: Path) -> list[dict[str, Any]]:
    """Every outcome row under ``folder`` (its ``outcomes.jsonl`` files, any depth)."""
    rows = []
    for path in sorted(folder.rglob("outcomes.jsonl")):
        rows += [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    if not rows:
        raise SystemExit(f"first_hour: no outcomes.jsonl under {folder}")
    return rows


def results(rows: Iterable[dict[str, Any]]) -> dict[str, dict[str, list[int]]]:
    """``{method: {split: [successes, episodes]}}``, splits in the order seen, unseen."""
    counts: dict[str, dict[str, list[int]]] = {}
    for row in sorted(rows, key=lambda r: (r["method"], r["split"] != "seen")):
        cell = counts.setdefault(row["method"], {}).setdefault(row["split"], [0, 0])
        cell[0] += bool(row["success"])
        cell[1] += 1
    return counts


def time_file(path: Path) -> tuple[float, float]:
    """Wall and CPU (user + system, children included) minutes from ``/usr/bin/time -v`` output."""
    text = path.read_text()
    user = float(re.search(r"User time \(seconds\): ([\d.]+)", text).group(1))
    system = float(re.search(r"System time \(seconds\): ([\d.]+)", text).group(1))
    wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", text).group(1)
    seconds = 0.0
    for part in wall.split(":"):
        seconds = seconds * 60 + float(part)
    return round(seconds / 60, 1), round((user + system) / 60, 1)


def cross_cpu(default: Path, other: Path, machine: str) -> dict[str, Any]:
    """How many episodes changed outcome between two ``abm zoo eval`` folders of the same seeds."""
    def key(row: dict[str, Any]) -> tuple[Any, ...]:
        return row["method"], row["task"], row["split"], row["repeat"], row["episode"], row["seed"]

    a = {key(r): r for r in outcomes(default)}
    b = {key(r): r for r in outcomes(other)}
    if set(a) != set(b):
        raise SystemExit(f"first_hour: {default} and {other} hold different episodes")
    flipped = [k for k in a if bool(a[k]["success"]) != bool(b[k]["success"])]
    per_cell = Counter(k[:3] for k in flipped)
    return {"kernels": AVX2, "episodes": len(a), "differing": len(flipped),
            "cells": len({k[:3] for k in a}), "cells_differing": len(per_cell),
            "max_per_cell": max(per_cell.values(), default=0),
            "identical_trajectories": sum(a[k]["trajectory"] == b[k]["trajectory"] for k in a), "machine": machine}


def help_seconds(runs: int = 5) -> float:
    """Median wall seconds of ``python -m abm.cli --help``."""
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "abm.cli", "--help"], capture_output=True, check=True)
        times.append(time.perf_counter() - start)
    return round(statistics.median(times), 2)


def render_ms(output: str) -> float:
    """``benchmarks/render_speed.py``'s milliseconds per call for 100k points, batch 1."""
    found = re.search(r"^\| 100k \| 1 \| ([\d.]+) \|", output, re.M)
    if not found:
        raise SystemExit("first_hour: no '| 100k | 1 |' row in render_speed.py's output")
    return float(found.group(1))


def policy_step(output: str) -> dict[str, float]:
    """``benchmarks/policy_speed.py``'s median seconds per step of the small and paper presets (CPU) and the paper
    preset's parameter count."""
    runs = {r["preset"]: r for r in map(json.loads, re.findall(r"^\{.*\}$", output, re.M))
            if r.get("device") == "cpu" and "preset" in r}
    if not {"small", "paper"} <= set(runs):
        raise SystemExit(f"first_hour: policy_speed.py measured {sorted(runs)}, not small and paper on the CPU")
    return {"policy_small_s": runs["small"]["median_s"], "policy_paper_s": runs["paper"]["median_s"],
            "paper_parameters": runs["paper"]["parameters"]}


def mask_field_s(output: str) -> float:
    """``benchmarks/grounding_speed.py``'s mask field total (seconds) of its vit-b16 row."""
    found = re.search(r"^\| vit-b16 \|(?:[^|]*\|){4}\s*([\d.]+) \|", output, re.M)
    if not found:
        raise SystemExit("first_hour: no vit-b16 row in grounding_speed.py's output")
    return float(found.group(1))


def train_samples_per_s(output: str) -> float:
    """``benchmarks/train_speed.py``'s samples per second (its last JSON line)."""
    lines = re.findall(r"^\{.*\}$", output, re.M)
    if not lines:
        raise SystemExit("first_hour: no JSON result in train_speed.py's output")
    return float(json.loads(lines[-1])["samples_per_s"])


def generation_range(output: str) -> list[float]:
    """``benchmarks/generation_throughput.py``'s lowest and highest episodes per minute over its tasks."""
    rates = [float(r) for r in re.findall(r"^\| \w+ \| \d+ \| \d+ \| ([\d.]+) \|", output, re.M)]
    if not rates:
        raise SystemExit("first_hour: no task rows in generation_throughput.py's output")
    return [min(rates), max(rates)]


SPEED_PARSERS = {"benchmarks/render_speed.py": lambda out: {"render_ms": render_ms(out)},
                 "benchmarks/policy_speed.py": policy_step,
                 "benchmarks/grounding_speed.py": lambda out: {"mask_field_s": mask_field_s(out)},
                 "benchmarks/train_speed.py": lambda out: {"train_samples_per_s": train_samples_per_s(out)},
                 "benchmarks/generation_throughput.py": lambda out: {"generation_episodes_per_min":
                                                                     generation_range(out)}}
"""What each command of the README's speed table contributes to the ``speed`` section, by its script."""


def speed(commands: Iterable[str]) -> dict[str, Any]:
    """Run the speed table's commands (``python SCRIPT ARGS``, from the checkout, this interpreter) one after
    another and parse what each measured."""
    values: dict[str, Any] = {}
    for command in commands:
        args = command.split()[1:]
        print(f"first_hour: {command}", flush=True)
        done = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                              env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})
        if done.returncode != 0:
            raise SystemExit(f"first_hour: '{command}' failed:\n{done.stderr[-2000:]}")
        values.update(SPEED_PARSERS[args[0]](done.stdout))
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quickstart", type=Path, help="the quickstart's output folder (its outcomes)")
    parser.add_argument("--quickstart-time", type=Path, help="/usr/bin/time -v output of the quickstart")
    parser.add_argument("--quickstart-load", default="nothing else ran", help="what else ran meanwhile")
    parser.add_argument("--quickstart-grounder", default="benchmark CLIP (models/benchmark-clip)")
    parser.add_argument("--zoo-eval", type=Path, help="abm zoo eval's output folder (default kernels)")
    parser.add_argument("--zoo-eval-minutes", type=float, help="its wall minutes on idle cores")
    parser.add_argument("--cross-cpu", type=Path, help="abm zoo eval's output folder with AVX-512 switched off")
    parser.add_argument("--help-time", action="store_true", help="time abm --help now")
    parser.add_argument("--tests", type=float, nargs=2, metavar=("PYTEST_MIN", "CI_MIN"),
                        help="the test script's minutes: pytest alone, .ci/run on a fresh clone")
    parser.add_argument("--speed", action="store_true", help="run the README speed table's commands now")
    parser.add_argument("--commit", default=None, help="the commit the runs measured (default: that of the checkout "
                        "their folder lies in, else this one)")
    parser.add_argument("--machine", default=None, help="the machine the runs were measured on (default: this one)")
    args = parser.parse_args(argv)
    machine = args.machine or this_machine()
    today = datetime.date.today().isoformat()
    data: dict[str, Any] = json.loads(FILE.read_text()) if FILE.is_file() else {}
    if args.quickstart:
        if not args.quickstart_time:
            parser.error("--quickstart needs --quickstart-time")
        wall, cpu = time_file(args.quickstart_time)
        data["quickstart"] = {"wall_minutes": wall, "cpu_minutes": cpu, "machine": machine, "date": today,
                              "commit": args.commit or commit(args.quickstart), "grounder": args.quickstart_grounder,
                              "load": args.quickstart_load, "results": results(outcomes(args.quickstart))}
    if args.zoo_eval:
        if args.zoo_eval_minutes is None:
            parser.error("--zoo-eval needs --zoo-eval-minutes")
        data["zoo_eval"] = {"wall_minutes": args.zoo_eval_minutes, "machine": machine, "date": today,
                            "commit": args.commit or commit(args.zoo_eval), "results": results(outcomes(args.zoo_eval))}
        if args.cross_cpu:
            data["cross_cpu"] = cross_cpu(args.zoo_eval, args.cross_cpu, machine)
    if args.help_time:
        data["help"] = {"seconds": help_seconds(), "machine": machine}
    if args.tests:
        data["tests"] = {"pytest_minutes": args.tests[0], "ci_minutes": args.tests[1], "machine": machine}
    sys.path.insert(0, str(ROOT / "src"))
    from abm import measured
    from abm.experiments.report.pages import first_hour

    if args.speed:
        commands = [r.command for r in first_hour.SPEED_ROWS if r.command]
        data["speed"] = {**speed(commands), "machine": machine, "date": today, "commit": args.commit or commit(ROOT)}
    FILE.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")

    measured.measured.cache_clear()
    for path in first_hour.write(ROOT):
        print(f"first_hour: wrote {path.relative_to(ROOT)}")
    print(f"first_hour: {FILE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
