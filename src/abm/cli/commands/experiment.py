"""``abm experiment run|status|list`` (the parser: :mod:`abm.cli.experiment`; the engine: :mod:`abm.experiments`)."""

from __future__ import annotations

import argparse
import signal
from collections import Counter
from types import FrameType

from abm.experiments.scheduler import Source
from abm.experiments.spec import builtin_specs, load_spec
from abm.experiments.stages import Engine
from abm.experiments.status import carried_lines, estimate, kept_line, readme_gate_lines, stage_time_lines


def _engine(args: argparse.Namespace) -> Engine:
    source = Source.at(args.source) if getattr(args, "source", None) else None
    return Engine(load_spec(args.spec), root=args.root, out=args.out, source=source, runs=args.runs,
                  backend=getattr(args, "backend", "local"), ray_address=getattr(args, "ray_address", None),
                  threads=getattr(args, "threads", None))


def _interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt  # SIGTERM like Ctrl-C: the engine stops its jobs and carries their state


def run(args: argparse.Namespace) -> int:
    engine = _engine(args)
    print(f"abm experiment run {engine.spec.name}: stages {' '.join(args.stages)}, working folder "
          f"{engine.rel(engine.layout.out)}")
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        return engine.run(args.stages, dry_run=args.dry_run)
    finally:
        signal.signal(signal.SIGTERM, previous)


def status(args: argparse.Namespace) -> int:
    engine = _engine(args)
    jobs = engine.status()
    print(f"{engine.spec.name} ({engine.spec.path.name}), working folder {engine.rel(engine.layout.out)}")
    if engine.spec.finished:
        print(f"finished: {engine.spec.finished} (only its report runs)")
    width = max(len(j.id) for j in jobs)
    print(f"{'job':{width}s}  {'state':8s} {'min':>7s}  note")
    for job in jobs:
        minutes = f"{job.minutes:7.1f}" if job.minutes is not None else " " * 7
        print(f"{job.id:{width}s}  {job.state:8s} {minutes}  {job.note}")
    counts = Counter(j.state for j in jobs)
    print(", ".join(f"{state} {counts[state]}" for state in ("done", "running", "left", "blocked", "failed")
                    if counts[state]))
    spec, layout = engine.spec, engine.layout
    sources = [s.source for s in (*spec.report.summary, *spec.report.details,
                                  *(s for b in spec.report.blocks.values() for s in b)) if s.source]
    for line in (*stage_time_lines(layout, jobs), *readme_gate_lines(spec, layout), kept_line(layout, sources),
                 *carried_lines(layout), *estimate(spec, layout, jobs)):
        print(line)
    return 0


def list_specs(args: argparse.Namespace) -> int:
    for name in builtin_specs():
        spec = load_spec(name)
        print(f"{name:18s} {spec.about}")
    return 0
