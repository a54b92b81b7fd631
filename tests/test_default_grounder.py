"""One grounder resolution order for every command (abm.grounding.default): --clip-model, else the pretrained
CLIP if cached, else the benchmark CLIP, else the oracle with a loud warning; train, ground, eval and the
quickstart use it and say what they picked; abm eval without --out never writes into the model zoo."""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import pytest

import abm.grounding.default as default
from abm.configuration import CPU_CLIP_MODEL, GPU_CLIP_MODEL


@pytest.fixture
def machine(tmp_path, monkeypatch):
    """A machine whose CLIP weights are the names in the returned set (and a benchmark CLIP folder to add)."""
    present: set[str] = set()
    bench = tmp_path / "bench"
    monkeypatch.setenv(default.BENCHMARK_CLIP_ENV, str(bench))
    monkeypatch.setattr(default, "clip_present", lambda model: model in present)
    return present, str(bench)


def test_the_order_is_given_then_pretrained_then_benchmark_then_oracle(machine, capsys):
    present, bench = machine
    choice = default.default_grounder()
    assert (choice.kind, choice.model, choice.source) == ("oracle", None, "oracle")
    err = capsys.readouterr().err
    assert "using the ORACLE grounder" in err and f"abm clip train --out {bench}" in err  # loud, and says how
    present.add(bench)
    assert default.default_grounder().options == {"model": bench}
    assert "benchmark CLIP" in default.default_grounder().startup_line("train")
    present.add(CPU_CLIP_MODEL)
    assert (default.default_grounder().model, default.default_grounder().source) == (CPU_CLIP_MODEL, "pretrained")
    assert default.default_grounder(device="cuda").model == bench  # the GPU-sized CLIP is not cached
    present.add("mine")
    given = default.default_grounder("mine")
    assert (given.model, given.source) == ("mine", "given")
    assert given.startup_line("ground") == "abm ground: grounder: CLIP mine (--clip-model)"
    with pytest.raises(ValueError, match="--clip-model missing.*models/benchmark-clip"):  # never another grounder
        default.default_grounder("missing")


def test_a_clip_asked_for_is_never_the_oracle_and_the_error_names_the_committed_clip(machine):
    with pytest.raises(ValueError, match="models/benchmark-clip.*abm clip train"):
        default.default_grounder(clip_only=True)


def test_the_pretrained_clip_is_downloaded_only_when_allowed(machine):
    present, _ = machine
    fetched = []

    def loader(model, allow):
        fetched.append((model, allow))
        present.add(model)

    assert default.default_grounder(loader=loader).kind == "oracle" and not fetched
    choice = default.default_grounder(device="cuda", download=True, loader=loader)
    assert choice.model == GPU_CLIP_MODEL and fetched == [(GPU_CLIP_MODEL, True)]


def test_clip_present_reads_folders_without_loading(tmp_path):
    assert not default.clip_present(str(tmp_path))
    (tmp_path / "config.json").write_text("{}")
    assert default.clip_present(str(tmp_path)) and default.clip_present("tiny")
    assert not default.clip_present(str(tmp_path / "missing"))


def test_benchmark_clip_dir_prefers_the_environment_then_the_checkout(tmp_path, monkeypatch):
    monkeypatch.delenv(default.BENCHMARK_CLIP_ENV, raising=False)
    monkeypatch.chdir(tmp_path)
    assert default.benchmark_clip_dir() == Path(default.DEFAULT_BENCHMARK_CLIP).expanduser()
    (tmp_path / "models/benchmark-clip").mkdir(parents=True)
    (tmp_path / "models/benchmark-clip/config.json").write_text("{}")
    assert default.benchmark_clip_dir() == default.ZOO_BENCHMARK_CLIP
    monkeypatch.setenv(default.BENCHMARK_CLIP_ENV, str(tmp_path / "x"))
    assert default.benchmark_clip_dir() == tmp_path / "x"


def _train_args(tmp_path: Path, *words: str) -> argparse.Namespace:
    from abm.cli import build_parser

    return build_parser().parse_args(["train", "--method", "abm", "--steps", "10", "--data", str(tmp_path), "--out",
                                     str(tmp_path / "run"), *words])


def test_abm_train_without_grounder_uses_the_order(machine, tmp_path, capsys):
    from abm.cli.commands.train import train_grounder

    present, bench = machine
    args = _train_args(tmp_path)
    assert args.grounder is None  # the parser leaves the choice to the order
    present.add(bench)
    assert train_grounder(args) == ("clip", bench)
    assert f"abm train: grounder: benchmark CLIP trained on ABM-Bench renders ({bench}" in capsys.readouterr().out
    assert train_grounder(_train_args(tmp_path, "--clip-model", bench)) == ("clip", bench)
    synthetic = _train_args(tmp_path)
    synthetic.data = None
    assert train_grounder(synthetic) == ("oracle", None)
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"train": {"grounder": "oracle", "grounder_options": {}}}))
    assert train_grounder(_train_args(tmp_path, "--resume")) == ("oracle", None)  # a resumed run keeps its own
    assert _train_args(tmp_path, "--grounder", "oracle").grounder == "oracle"


def test_abm_train_config_quickstart_trains_with_the_quickstarts_grounder(machine, tmp_path, capsys):
    import abm.cli.commands.quickstart as qs
    from abm.cli.commands.train import train_grounder

    present, bench = machine
    present.add(bench)
    quick = qs.choose_grounder(qs.QuickstartConfig(offline=True))
    assert quick[:2] == ("clip", {"model": bench})
    assert train_grounder(_train_args(tmp_path, "--config", "quickstart")) == ("clip", bench)
    out = capsys.readouterr().out
    assert "abm quickstart: grounder: benchmark CLIP" in out and "abm train: grounder: benchmark CLIP" in out


def test_abm_ground_leaves_the_grounder_to_the_order():
    from abm.cli import build_parser

    args = build_parser().parse_args(["ground"])
    assert args.grounder is None and args.clip_model is None


def test_abm_eval_without_out_never_writes_into_the_zoo(tmp_path, monkeypatch):
    from abm.evaluation.session import default_eval_base

    monkeypatch.chdir(tmp_path)
    zoo = tmp_path / "models"
    zoo.mkdir()
    (zoo / "index.json").write_text("[]")
    (zoo / "abm_clip.pt").write_bytes(b"")
    assert default_eval_base(zoo / "abm_clip.pt") == Path("runs/eval/abm_clip")
    run = tmp_path / "runs/abm"
    run.mkdir(parents=True)
    (run / "config.json").write_text("{}")
    assert default_eval_base(run) == run  # a training run folder holds its own evaluations
    inside = zoo / "abm_run"
    inside.mkdir()
    (inside / "config.json").write_text("{}")
    assert default_eval_base(inside) == Path("runs/eval/abm_run")
    (run / "checkpoints").mkdir()
    (run / "checkpoints/step_2.pt").write_bytes(b"")
    assert default_eval_base(run / "checkpoints/step_2.pt") == Path("runs/eval/step_2")


def test_abm_eval_records_its_protocol():
    from abm.evaluation.results import eval_seed
    from abm.evaluation.session import EvalRequest, eval_protocol
    from abm.evaluation.settings import EvalSettings

    request = EvalRequest(runs=[Path("models/abm_clip.pt")], episodes=3, repeats=2)
    protocol = eval_protocol(request, {"seen": ["pick_block"]})
    assert protocol["seeds"] == [[eval_seed(r, e) for e in range(3)] for r in range(2)]
    assert protocol["seeds_text"] == f"{eval_seed(0, 0)}-{eval_seed(0, 2)}, {eval_seed(1, 0)}-{eval_seed(1, 2)}"
    assert protocol["command"] == ("abm eval --run models/abm_clip.pt --split seen --episodes 3 --repeats 2 "
                                   f"--max-steps {EvalSettings().max_steps} --resolution {EvalSettings().resolution}")
    one = replace(request, episodes=1, repeats=1, tasks=["pick_block"], settings=EvalSettings(grounder="oracle"))
    protocol = eval_protocol(one, {"seen": ["pick_block"]})
    assert protocol["seeds_text"] == str(eval_seed(0, 0))
    assert "--tasks pick_block --grounder oracle" in protocol["command"]
    json.dumps(protocol)


def _outcome(method: str, episode: int, success: bool, repeat: int = 0, error: str = ""):
    from abm.evaluation.results import EpisodeOutcome

    return EpisodeOutcome(method, "pick_block", "seen", repeat, episode, 1000 + episode, success, 1, 0.0,
                          error=error)


def test_gifs_show_a_fixed_mix_of_successes_and_failures():
    from abm.evaluation.session import gif_choice

    wins = [1, 3, 4, 6]
    outcomes = [_outcome("abm", e, e in wins) for e in range(8)] + [_outcome("abm", 0, True, repeat=1)]
    shown = lambda n: [(o.episode, o.success) for o in gif_choice(outcomes, n)]  # noqa: E731
    assert shown(1) == [(1, True)]
    assert shown(2) == [(0, False), (1, True)]
    assert shown(3) == [(0, False), (1, True), (3, True)]
    assert shown(4) == [(0, False), (1, True), (2, False), (3, True)]
    only_losses = [_outcome("rvt", e, False) for e in range(3)] + [_outcome("rvt", 3, False, error="crash")]
    assert [o.episode for o in gif_choice(only_losses, 2)] == [0, 1]  # topped up; a crash is never shown
    assert len(gif_choice(outcomes + only_losses, 1)) == 2  # per method
