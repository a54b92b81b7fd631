"""Arms of an experiment beyond its trainings (issue 53): an evaluation variant that runs a trained model with the
expert's move keyframe (``expert_keyframes: move``), the grasp <-> lift loop rule on step records, and the
records file and targets the report writes from constructed outcomes with known medians."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from abm.evaluation.results import OUTCOME_ARCHIVE, EpisodeOutcome, write_outcome_archive
from abm.experiments import report as rep
from abm.experiments.arm_records import loops
from abm.experiments.spec import SpecError, load_spec
from abm.experiments.stages import Engine

TASKS = ("place_wine", "pick_block", "put_in_shelf", "insert_peg")


def _steps(*kinds: str) -> list[dict]:
    return [{"expert": kind} for kind in kinds]


def test_a_loop_is_grasp_lift_grasp_or_lift_grasp_lift_without_a_destination_step_between() -> None:
    assert loops(_steps("approach", "grasp", "lift", "grasp"))
    assert loops(_steps("grasp", "lift", "lift", "approach", "grasp", "lift"))  # repeats merge, approach skipped
    assert loops(_steps("approach", "lift", "grasp", "lift"))
    assert not loops(_steps("approach", "grasp", "lift", "move", "place", "retreat"))
    assert not loops(_steps("grasp", "lift", "move", "grasp"))  # a move between: no loop at the pick-up spot
    assert not loops(_steps("grasp", "lift", "place", "grasp"))
    assert not loops(_steps("grasp", "grasp", "lift", "lift"))
    assert not loops(_steps("", "grasp", "", "lift")) and not loops([])


def test_the_probe_spec_has_an_expert_move_arm_evaluated_from_v2s_model(tmp_path: Path) -> None:
    spec = load_spec("destination_probe")
    (arm,) = spec.evaluation.variants
    assert (arm.name, arm.run, arm.grounder, arm.expert_keyframes) == ("expert-move", "v2", "", "move")
    engine = Engine(spec, root=tmp_path)
    jobs = {j.id: j for j in engine.plan("eval")}
    assert {"eval/expert-move/seen", "eval/expert-move/unseen"} <= set(jobs)
    model = engine.layout.run_dir("v2") / "checkpoints"
    model.mkdir(parents=True)
    from abm.policy.checkpoint import save_checkpoint

    save_checkpoint(model / "step_00003000.pt", {"step": 3000})  # v2 trained: its arm can run
    jobs = {j.id: j for j in engine.plan("eval")}
    job = jobs["eval/expert-move/seen"]
    arm, plain = job.work.request, jobs["eval/v2/seen"].work.request
    assert arm.settings.expert_keyframes == "move" and arm.settings.grounder is None
    assert arm.runs == plain.runs and arm.out == Path("runs/destination_probe/eval/expert-move/seen")
    assert plain.settings.expert_keyframes is None


@pytest.mark.parametrize(("variant", "message"), [
    ({"run": "v2", "expert_keyframes": "place"}, r"expert_keyframes: expected one of move, got 'place'"),
    ({"run": "v2", "grounder": "clip"}, r"a variant is named RUN@GROUNDER \(v2@clip\)"),
])
def test_an_arm_mistake_names_the_key(tmp_path: Path, variant: dict, message: str) -> None:
    data = yaml.safe_load(load_spec("destination_probe").path.read_text())
    data["evaluation"]["variants"] = {"expert-move": variant}
    path = tmp_path / "probe.yaml"
    path.write_text(yaml.safe_dump(data, allow_unicode=True))
    with pytest.raises(SpecError, match=message):
        load_spec(path)
    data["evaluation"]["variants"] = {"v2": {"run": "v2", "expert_keyframes": "move"}}
    path.write_text(yaml.safe_dump(data, allow_unicode=True))
    with pytest.raises(SpecError, match="needs a plain name that is no run's, got 'v2'"):
        load_spec(path)
    data["evaluation"]["variants"] = {}
    data["report"]["summary"] = [{"kind": "targets", "text": "t", "runs": ["v2"],
                                  "checks": [{"text": "x", "kind": "keyframe_cm", "split": "seen", "value": 2}]}]
    path.write_text(yaml.safe_dump(data, allow_unicode=True))
    with pytest.raises(SpecError, match=r"checks\[0\]\.keyframe: a keyframe kind goes with a keyframe_cm"):
        load_spec(path)


def _rate(task: str, split: str, mean: float) -> dict:
    return {"method": "abm", "task": task, "split": split, "per_repeat": [mean], "episodes": 20, "errors": 0,
            "mean": mean, "std": 0.0}


def _diagnosis(rows: list[tuple[str, str, float, float]]) -> dict:
    """(task, split, position cm, rotation °) rows of the move keyframe, as the diagnosis writes its summary."""
    return {"summary": [{"task": t, "split": s, "kind": "move", "position_cm_median": cm, "rotation_deg_median": deg}
                        for t, s, cm, deg in rows]}


def _outcome(task: str, split: str, episode: int, kinds: tuple[str, ...]) -> EpisodeOutcome:
    records = [{"pos": [0, 0, 0], "quat": [0, 0, 0, 1], "yaw": 0, "open": False, "straight": False,
                "motion": "reached", "stop_cm": 0.1, "held": True, "expert": k, "expert_i": 0, "expert_cm": 1.0,
                "expert_deg": 1.0} for k in kinds]
    return EpisodeOutcome("abm", task, split, 0, episode, episode, False, len(kinds), 1.0, step_records=records)


def test_the_report_writes_every_arms_records_and_states_each_target(tmp_path: Path) -> None:
    spec = load_spec("destination_probe")
    layout = Engine(spec, root=tmp_path).layout
    means = {("v2", "seen"): 40.0, ("v2", "unseen"): 40.0, ("destination", "seen"): 60.0,
             ("destination", "unseen"): 50.0, ("expert-move", "seen"): 80.0}
    for (arm, split), mean in means.items():
        folder = layout.eval_dir(arm, split)
        folder.mkdir(parents=True)
        (folder / "results.json").write_text(json.dumps([_rate(t, split, mean) for t in TASKS]))
        looping = ("approach", "grasp", "lift", "grasp", "lift")
        fine = ("approach", "grasp", "lift", "move", "place")
        write_outcome_archive([_outcome(t, split, e, looping if (arm, t, e) == ("destination", "pick_block", 1)
                                        and split == "seen" else fine) for t in TASKS for e in range(2)],
                              folder / OUTCOME_ARCHIVE)
    layout.diagnosis("destination").parent.mkdir(parents=True)
    # seen: position 1, 1.5, 2.5, 3 (median 2.0), rotation 10, 12, 14, 40 (median 13); unseen: 3 cm, 20° each
    layout.diagnosis("destination").write_text(json.dumps(_diagnosis(
        [(t, "seen", cm, deg) for t, cm, deg in zip(TASKS, (1.0, 1.5, 2.5, 3.0), (10.0, 12.0, 14.0, 40.0),
                                                   strict=True)] + [(t, "unseen", 3.0, 20.0) for t in TASKS])))
    rep.write_report(spec, layout, figures=False)

    records = json.loads((tmp_path / "docs/results/destination_probe.json").read_text())
    assert records["accuracy"][0] == {"arm": "destination", "task": "place_wine", "split": "seen", "keyframe": "move",
                                      "yaw_error_deg": 10.0, "position_error_cm": 1.0}
    assert len(records["accuracy"]) == 8
    assert {"arm": "v2", "task": "insert_peg", "split": "unseen", "successes": 8, "episodes": 20} in records["rollouts"]
    assert [r["arm"] for r in records["rollouts"]][::4] == ["v2", "v2", "destination", "destination", "expert-move"]
    assert {"arm": "destination", "task": "pick_block", "split": "seen", "loops": 1, "episodes": 2} in records["loops"]
    assert sum(r["loops"] for r in records["loops"]) == 1

    page = (tmp_path / "docs/results/destination_probe.md").read_text()
    targets = next(line for line in page.splitlines() if line.startswith("Targets of the destination arm"))
    for verdict in ("move keyframe position ≤ 2 cm, seen: met (2.0 cm)",
                    "move keyframe position ≤ 2 cm, unseen: not met (3.0 cm)",
                    "move keyframe yaw ≤ 15°, seen: met (13.0°)", "move keyframe yaw ≤ 15°, unseen: not met (20.0°)",
                    "rollouts ≥ v2 + 15 points, seen: met (60.0 vs 40.0)",
                    "rollouts ≥ v2 + 15 points, unseen: not met (50.0 vs 40.0)", "unseen ≥ 0.9 × seen: not met",
                    "loops ≤ 2 % of episodes, seen: not met (12.5 % of 8 episodes)",
                    "loops ≤ 2 % of episodes, unseen: met (0.0 % of 8 episodes)"):
        assert verdict in targets, verdict
    assert "destination-clip: " in targets and "not evaluated yet" in targets.split("destination-clip: ")[1]
    assert "| + progress + destination mask | 1 / 8 (12 %) | 0 / 8 (0 %) |" in page
    assert "| v2, the expert's move keyframe | 0 / 8 (0 %) | – |" in page
    rep.write_report(spec, layout, figures=False)  # the report's own records file: replaced, not refused
