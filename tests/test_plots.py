"""Result figures: the success bar chart and training curves, in the evaluation report and in the README
images that the experiments' report (abm.experiments.report) draws from the committed JSON."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from abm.evaluation.plots import keyframe_error_curve, loss_curves, run_loss_curves, success_chart
from abm.evaluation.results import EpisodeOutcome, aggregate, eval_seed
from abm.evaluation.runner import write_reports
from abm.experiments.report import collect_cells, draw_figures, keep_training_log
from abm.experiments.spec import load_spec
from abm.experiments.state import Layout, restore

ROOT = Path(__file__).resolve().parents[1]
TAB_BLUE, TAB_ORANGE, TAB_GREEN = (31, 119, 180), (255, 127, 14), (44, 160, 44)


def _has_colour(png: Path, rgb: tuple[int, int, int], min_pixels: int = 50) -> bool:
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    return int((np.abs(img - np.array(rgb)).sum(-1) < 6).sum()) >= min_pixels


def _outcomes() -> list[EpisodeOutcome]:
    out = []
    for method, wins in (("abm", [[1, 1, 0, 1], [1, 0, 0, 1]]), ("rvt", [[0, 0, 1, 0], [0, 0, 0, 0]])):
        for split in ("seen", "unseen"):
            for rep, row in enumerate(wins):
                for ep, w in enumerate(row):
                    out.append(EpisodeOutcome(method, "pick_block", split, rep, ep, eval_seed(rep, ep), bool(w)))
    return out


def test_success_chart_draws_one_bar_colour_per_method_and_a_panel_per_split(tmp_path):
    rates = aggregate(_outcomes())
    two = success_chart(rates, tmp_path / "two.png")
    assert _has_colour(two, TAB_BLUE) and _has_colour(two, TAB_ORANGE) and not _has_colour(two, TAB_GREEN)
    three = success_chart([*rates, *[r for r in aggregate([EpisodeOutcome("ifd", "pick_block", "seen", 0, 0, 1,
                                                                           True)])]],
                          tmp_path / "three.png", methods=["abm", "rvt", "ifd"])
    assert _has_colour(three, TAB_GREEN)
    comp = success_chart([*rates, *aggregate([EpisodeOutcome("abm", "put_in_container", "compositional", 0, 0, 1,
                                                              False)])], tmp_path / "comp.png")
    assert Image.open(comp).width > Image.open(two).width  # a third panel
    with pytest.raises(ValueError, match="no success rates"):
        success_chart([], tmp_path / "none.png")


def test_eval_report_links_the_chart_and_the_training_curves(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "log.csv").write_text("step,total,translation,rotation,gripper\n" +
                                 "".join(f"{s},{2 / s},{1 / s},{0.5 / s},{0.1 / s}\n" for s in range(1, 30)))
    out = tmp_path / "eval"
    assert run_loss_curves({"abm": run, "rvt": tmp_path / "no_log"}, out / "training.png")
    assert run_loss_curves({"rvt": str(tmp_path / "no_log")}, tmp_path / "x.png") is None
    write_reports(_outcomes(), out)
    assert _has_colour(out / "success.png", TAB_BLUE) and _has_colour(out / "training.png", TAB_BLUE)
    md = (out / "results.md").read_text()
    assert "](success.png)" in md and "](training.png)" in md
    page = (out / "report.html").read_text()
    assert "<img src='success.png'" in page and "<img src='training.png'" in page


def test_keyframe_error_and_loss_curves(tmp_path):
    rows = [{"method": m, "task": t, "split": "seen", "kind": "grasp", "position_cm_median": v}
            for m, v in (("abm@1000", 2.0), ("abm@2000", 1.0), ("abm", 0.5)) for t in ("a", "b")]
    png = keyframe_error_curve(rows, tmp_path / "k.png")
    assert _has_colour(png, TAB_BLUE, 20)
    with pytest.raises(ValueError, match="no place keyframes"):
        keyframe_error_curve(rows, tmp_path / "k.png", kind="place")
    rows = [{"step": "1", "total": "1.0"}, {"step": "2", "total": ""}, {"step": "3", "total": "0.1"}]
    assert _has_colour(loss_curves({"abm": rows}, tmp_path / "l.png", heads=("total",)), TAB_BLUE)


@pytest.mark.parametrize("name, images", [("seen_unseen", ["seen_unseen_success", "seen_unseen_training"]),
                                          ("clip_grounder", ["clip_grounder_losses", "clip_grounder_success"])])
def test_readme_images_are_what_the_report_draws_from_the_committed_json(tmp_path, name, images):
    spec = load_spec(name)
    layout = Layout.of(spec, ROOT, tmp_path / "out")  # reads the committed outcomes, draws into tmp_path
    spec = replace(spec, report=replace(spec.report, figures=tuple(
        replace(f, file=str(tmp_path / Path(f.file).name)) for f in spec.report.figures)))
    restore(spec, layout)
    drawn = {png.stem: png for png in draw_figures(spec, layout, collect_cells(spec, layout))}
    assert sorted(drawn) == sorted(images)
    readme = (ROOT / "README.md").read_text()
    for image in images:
        committed = ROOT / "docs" / "images" / "results" / f"{image}.png"
        assert f"](docs/images/results/{image}.png)" in readme
        assert Image.open(committed).size == Image.open(drawn[image]).size
        a = np.asarray(Image.open(committed).convert("RGB")).astype(int)
        b = np.asarray(Image.open(drawn[image]).convert("RGB")).astype(int)
        assert np.abs(a - b).mean() < 2.0  # the same figure (fonts may differ by a few pixels across machines)


def test_the_report_keeps_compact_loss_curves_and_draws_them(tmp_path):
    spec = load_spec("clip_grounder")
    layout = Layout.of(spec, tmp_path, tmp_path / "out")
    run = layout.run_dir("abm_clip")
    run.mkdir(parents=True)
    (run / "log.csv").write_text("step,total,translation,rotation,gripper,elapsed_s\n" +
                                 "".join(f"{s},{9 / s},{5 / s},{3 / s},{1 / s},{s}\n" for s in range(1, 1001)))
    keep_training_log(run, layout.kept / "training_abm_clip.csv")
    kept = (layout.kept / "training_abm_clip.csv").read_text().splitlines()
    assert kept[0] == "step,total,translation,rotation,gripper" and kept[-1].startswith("1000,")
    assert 150 < len(kept) < 260  # at most ~200 rows and the last one
    for split in ("seen", "unseen"):
        layout.eval_dir("abm_clip", split).mkdir(parents=True)
        (layout.eval_dir("abm_clip", split) / "results.json").write_text(
            (ROOT / f"docs/results/clip_grounder/abm_clip_{split}.json").read_text())
    drawn = {png.stem: png for png in draw_figures(spec, layout, collect_cells(spec, layout))}
    assert sorted(drawn) == ["clip_grounder_losses", "clip_grounder_success"]
    assert _has_colour(drawn["clip_grounder_losses"], TAB_BLUE)
