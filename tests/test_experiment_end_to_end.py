"""A tiny experiment end to end through ``abm experiment run`` (real subprocesses, the simulator): 2 tasks, 1
demonstration each, two runs trained side by side for 2 steps with a tiny model, exported, evaluated on 1
episode per task, reported; a rerun does nothing and ``abm experiment status`` says everything is done."""

from __future__ import annotations

import json
import re
from pathlib import Path

import yaml

from sim_helpers import require_simulator

require_simulator("h5py", libero=True)

from abm.cli import main  # noqa: E402
from abm.evaluation.results import read_outcome_archive  # noqa: E402

TINY_MODEL = {"resolution": 32, "patch_size": 8, "width": 32, "layers_within": 1, "layers_joint": 1, "heads": 2,
              "stem_channels": 8, "decoder_channels": 8, "rotation_bins": 36}
SPEC = {
    "name": "tiny",
    "about": "two tasks, one episode, two steps: the engine end to end",
    "out": "runs/tiny", "kept": "docs/results/tiny", "zoo": "models",
    "tasks": {"two": ["pick_block", "place_food"]},
    "data": {"tasks": "two", "episodes": 1, "workers": 1, "resolution": 32},
    "training": {"recipe": "quickstart", "tasks": "two", "steps": 2,
                 "train": {"batch": 2, "checkpoint_every": 2, "warmup": 1, "verify": False},
                 "policy": TINY_MODEL},
    "runs": {"abm_oracle": {"label": "ABM (oracle mask)", "train": {"method": "abm", "grounder": "oracle"}},
             "rvt_hash": {"label": "RVT (hash text)", "train": {"method": "rvt", "language": "hash"}}},
    "evaluation": {"from_zoo": True, "episodes": 1, "repeats": 1, "workers": 1, "max_steps": 1,
                   "splits": {"seen": {"tasks": "two"}}},
    "resources": {"trainings_at_a_time": 2, "threads_each": 1},
    "report": {"title": "Tiny", "document": "docs/results/tiny.md", "records": "docs/results/tiny.json",
               "readme": "README.md", "block": "tiny", "zoo_readme": True,
               "summary": [{"kind": "setup"},
                           {"kind": "per_task", "table": 1, "title": "Success:", "runs": ["abm_oracle", "rvt_hash"],
                            "splits": ["seen"]}]},
}


def test_a_tiny_experiment_runs_end_to_end_and_reports(tmp_path: Path, capsys, monkeypatch) -> None:
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    (tmp_path / "tiny.yaml").write_text(yaml.safe_dump(SPEC, sort_keys=False))
    (tmp_path / "README.md").write_text("# tiny\n\n<!-- tiny:start -->\n<!-- tiny:end -->\nend\n")
    args = ["experiment", "run", str(tmp_path / "tiny.yaml"), "--root", str(tmp_path)]
    assert main(args) == 0, capsys.readouterr().err
    records = json.loads((tmp_path / "docs/results/tiny.json").read_text())
    assert sorted((r["run"], r["task"]) for r in records) == [
        ("abm_oracle", "pick_block"), ("abm_oracle", "place_food"), ("rvt_hash", "pick_block"),
        ("rvt_hash", "place_food")]
    assert all(r["episodes"] == 1 and r["table"] == 1 for r in records)
    readme = (tmp_path / "README.md").read_text()
    block = readme.split("<!-- tiny:start -->\n")[1].split("<!-- tiny:end -->")[0]
    assert block.startswith("Written by `abm experiment run tiny` ([tiny.yaml](tiny.yaml))")
    assert "| task | ABM (oracle mask) seen | RVT (hash text) seen |" in block
    assert ("Recipe (every model): `small+custom` preset at 32² views over a 0.6 m cube, patch 8, 2 steps of "
            "batch 2") in block
    assert block.endswith("Full report: [docs/results/tiny.md](docs/results/tiny.md).\n") and readme.endswith("end\n")
    index = json.loads((tmp_path / "models/index.json").read_text())
    assert [e["name"] for e in index] == ["abm_oracle", "rvt_hash"] and index[0]["data"] == "runs/tiny/data"
    kept = sorted(p.name for p in (tmp_path / "docs/results/tiny").iterdir())
    assert kept == ["abm_oracle_seen.json", "abm_oracle_seen_outcomes.jsonl.xz", "machines.txt",
                    "rvt_hash_seen.json", "rvt_hash_seen_outcomes.jsonl.xz", "times.txt",
                    "training_abm_oracle.csv", "training_rvt_hash.csv"]  # the loss curves kept at the export
    # every episode committed beside its table, step by step, its checkpoint named inside the root
    episodes = read_outcome_archive(tmp_path / "docs/results/tiny/abm_oracle_seen_outcomes.jsonl.xz")
    assert sorted(o.task for o in episodes) == ["pick_block", "place_food"]
    assert all(len(o.step_records) == o.steps == 1 and o.checkpoint == "models/abm_oracle.pt" for o in episodes)
    curve = (tmp_path / "docs/results/tiny/training_abm_oracle.csv").read_text().splitlines()
    assert curve[0].startswith("step,total,translation,rotation") and curve[-1].startswith("2,")
    # no machine's folder in what the experiment commits
    for path in [*(tmp_path / "docs").rglob("*.*"), tmp_path / "README.md", *(tmp_path / "models").glob("*.*")]:
        if path.suffix in (".md", ".json", ".txt"):
            assert str(tmp_path) not in path.read_text(), path
    capsys.readouterr()
    assert main(args) == 0  # a rerun: every stage is done, nothing runs
    out = capsys.readouterr()
    assert "job(s)" not in out.err, out.err
    assert main(["experiment", "status", str(tmp_path / "tiny.yaml"), "--root", str(tmp_path)]) == 0
    status = capsys.readouterr().out
    # the counts (data, 2 trainings, 2 exports, 2 evaluations, report), the time per stage, then what is kept and
    # carried; nothing left, so no estimate
    counts, wall, jobs, kept_files, carried = status.splitlines()[-5:]
    assert counts == "done 8" and carried == "carried: nothing (this experiment keeps no carry)", status
    assert wall.startswith("wall time per stage, every session added up (min): data ") and "train " in wall, status
    assert re.search(r"eval \d+; \d+ in all$", wall), status
    assert jobs.startswith("job time per stage, each job's own minutes added up (min): "), status
    assert "train " in jobs and "(2 jobs)" in jobs, status
    assert re.fullmatch(r"kept: docs/results/tiny/ \(8 files, \d+ kB\)", kept_files), status
