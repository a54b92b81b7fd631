"""ABM-Bench tasks added for issue 4: the five remaining tasks and the two compositional ones.

Experts succeed on fixed seeds, predicates are false at the start (and on a wrong goal), scenes are
reproducible, splits keep unseen objects out of the seen split, evaluation-only tasks refuse
demonstration generation, ``--task all`` expands to the trainable tasks, ``abm tasks`` lists them.
Cameras are never rendered here (run_expert with record=False).
"""

import numpy as np
import pytest

from sim_helpers import require_simulator, teleport

require_simulator("h5py")

from abm.data.generate import EvaluationOnlyTaskError, expand_tasks, generate, trainable_tasks  # noqa: E402
from abm.language.instruction import decompose_instruction  # noqa: E402
from abm.sim.assets import libero_available  # noqa: E402
from abm.sim.env import make_env, run_expert  # noqa: E402
from abm.sim.splits import SplitFileError, load_splits  # noqa: E402
from abm.sim.tasks import TASKS, get_task  # noqa: E402

needs_libero = pytest.mark.skipif(not libero_available(), reason="LIBERO asset wheels not installed")

NEW_TASKS = ("put_in_shelf", "water_plants", "close_jar", "insert_peg", "take_off_pan")
COMPOSITIONAL = ("place_block_in_plate", "pick_food_to_target")
LIBERO_TASKS = {"put_in_shelf", "water_plants", "take_off_pan", "pick_food_to_target", "place_block_in_plate"}
CASES = [
    ("put_in_shelf", "seen", 0),
    ("water_plants", "unseen", 1),
    ("close_jar", "seen", 2),
    ("insert_peg", "unseen", 3),
    ("take_off_pan", "seen", 4),
    ("place_block_in_plate", "compositional", 0),
    ("pick_food_to_target", "compositional", 1),
]


def _case(task, split, seed):
    marks = [needs_libero] if task in LIBERO_TASKS else []
    return pytest.param(task, split, seed, marks=marks, id=f"{task}-{split}-{seed}")


def test_registry_has_the_eleven_tasks():
    assert {"place_food", "pick_block", "place_wine", *NEW_TASKS, *COMPOSITIONAL, "put_in_container"} <= set(TASKS)
    assert all(TASKS[t].evaluation_only for t in COMPOSITIONAL)
    assert not any(TASKS[t].evaluation_only for t in NEW_TASKS)


@pytest.mark.parametrize(("task", "split", "seed"), [_case(*c) for c in CASES])
def test_expert_succeeds_and_instruction_names_the_target(task, split, seed):
    with make_env(task, split, seed, resolution=16) as env:
        env.reset()
        assert not env.success()
        episode = run_expert(env, record=False)
        assert episode.success, episode.metadata["motions"]
        assert all(m == "reached" for m in episode.metadata["motions"])
        target, skill = decompose_instruction(env.instruction)
        assert target == env.target_names[0]
        assert "X" in skill


@pytest.mark.parametrize("task", [*NEW_TASKS, *COMPOSITIONAL])
def test_sampling_is_reproducible(task):
    split = "compositional" if task in COMPOSITIONAL else "seen"
    t = get_task(task)
    a, b, c = t.sample(11, split), t.sample(11, split), t.sample(12, split)

    def key(inst):
        return inst.instruction, [(o.name, o.x, o.y, o.yaw, o.z) for o in inst.scene.objects]

    assert key(a) == key(b)
    assert key(a) != key(c)


@pytest.mark.parametrize("task", NEW_TASKS)
def test_unseen_objects_never_appear_in_the_seen_split(task):
    splits = load_splits()
    unseen = {n for t in splits.tasks.values() for n in t.get("unseen", [])}
    seen_targets = set()
    for seed in range(12):
        inst = get_task(task).sample(seed, "seen")
        names = {o.name for o in inst.scene.objects}
        assert not names & unseen, (seed, names & unseen)
        seen_targets.add(inst.target_names[0])
    unseen_targets = {get_task(task).sample(s, "unseen").target_names[0] for s in range(12)}
    assert unseen_targets and unseen_targets <= set(splits.objects(task, "unseen"))
    assert not unseen_targets & seen_targets


def test_close_jar_predicate_wants_the_named_jar():
    from abm.sim.catalog import object_geometry
    from abm.sim.props import JAR_HALF_HEIGHT

    with make_env("close_jar", "seen", 5, resolution=16) as env:
        env.reset()
        sim, info = env.sim, env.instance.info
        lift = -object_geometry("jar lid").lower[2]
        other = next(i for i in range(len(sim.scene.objects)) if i not in (info["lid"], info["target"]))
        for jar, expected in ((other, False), (info["target"], True)):
            pose = sim.object_pose(jar)
            teleport(sim, info["lid"], [pose[0, 3], pose[1, 3], pose[2, 3] + JAR_HALF_HEIGHT + lift])
            assert env.success() is expected


def test_insert_peg_predicate_wants_the_named_peg():
    from abm.sim.props import PEG_HALF, RING_HALF_HEIGHT

    with make_env("insert_peg", "seen", 5, resolution=16) as env:
        env.reset()
        sim, info = env.sim, env.instance.info
        other = next(i for i in range(len(sim.scene.objects)) if i not in (info["ring"], info["target"]))
        for peg, expected in ((other, False), (info["target"], True)):
            pose = sim.object_pose(peg)
            teleport(sim, info["ring"], [pose[0, 3], pose[1, 3], RING_HALF_HEIGHT])
            assert env.success() is expected
        pose = sim.object_pose(info["target"])
        teleport(sim, info["ring"], [pose[0, 3], pose[1, 3], 2 * PEG_HALF[2] + 0.05])  # above the peg
        assert not env.success()


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("version: 1\ntasks:\n  close_jar:\n    seen: [red jar, gold jar]\n", "unknown objects.*gold jar"),
        ("version: 1\ntasks:\n  insert_peg:\n    seen: [red jar]\n", "not of the categories"),
        ("version: 1\ntasks:\n  water_plants:\n    seen: [tea pot]\n", "unknown objects.*tea pot"),
        ("version: 1\ntasks:\n  take_off_pan:\n    seen: [red block]\n", "not of the categories"),
        ("version: 1\ntasks:\n  close_jar:\n    seen: [red jar, blue jar]\n    unseen: [blue jar]\n",
         r"close_jar: \['blue jar'\] listed as both seen and unseen"),
    ],
)
def test_split_file_with_unknown_or_wrong_objects_fails_clearly(tmp_path, content, match):
    path = tmp_path / "splits.yaml"
    path.write_text(content)
    with pytest.raises(SplitFileError, match=match) as info:
        load_splits(path)
    assert str(path) in str(info.value)


def test_compositional_tasks_are_evaluation_only(tmp_path, capsys):
    from abm.cli import main

    for task in COMPOSITIONAL:
        assert set(load_splits().tasks[task]) == {"compositional"}
        with pytest.raises(EvaluationOnlyTaskError, match="evaluation-only"):
            generate(task, "compositional", 1, tmp_path, progress=False)
        with pytest.raises(SplitFileError, match="no split 'seen'"):
            make_env(task, "seen", 0)
        assert main(["data", "generate", "--task", task, "--split", "seen", "--episodes", "1",
                     "--out", str(tmp_path)]) == 2
        assert "evaluation-only" in capsys.readouterr().err
    assert not list(tmp_path.rglob("*.h5"))


def test_task_all_expands_to_the_trainable_tasks():
    expected = sorted(name for name, task in TASKS.items() if not task.evaluation_only)
    assert expand_tasks("all") == trainable_tasks() == expected
    assert {"place_food", "pick_block", "place_wine", *NEW_TASKS, "put_in_container"} <= set(expected)
    assert not set(COMPOSITIONAL) & set(expected)
    assert expand_tasks("close_jar, insert_peg") == ["close_jar", "insert_peg"]
    with pytest.raises(KeyError, match="unknown task"):
        expand_tasks("close_jar,fly")
    with pytest.raises(EvaluationOnlyTaskError):
        expand_tasks("pick_block,pick_food_to_target")


def test_data_generate_all_covers_every_trainable_task(tmp_path, monkeypatch, capsys):
    import abm.data.generate as gen
    import abm.data.stores as stores
    from abm.cli import main

    calls = []

    def fake_generate(task, split, episodes, out, **kwargs):
        calls.append((task, split))
        return gen.GenerationReport(episodes, 0, [], 1.0)

    monkeypatch.setattr(stores, "generate", fake_generate)
    assert main(["data", "generate", "--task", "all", "--split", "seen", "--episodes", "2",
                 "--out", str(tmp_path)]) == 0
    assert [t for t, _ in calls] == trainable_tasks()
    out = capsys.readouterr().out
    assert all(f"{t}/seen: 2 new" in out for t in trainable_tasks())


def test_abm_tasks_lists_templates_and_splits(capsys):
    from abm.cli import main

    assert main(["tasks"]) == 0
    out = capsys.readouterr().out
    for task in TASKS:
        assert task in out
    assert "put the X on the top shelf" in out and "evaluation only" in out
    assert "orange jar" in out
    assert main(["tasks", "--task", "nope"]) == 2


def test_water_plants_predicate_needs_tilt():
    with make_env("water_plants", "seen", 2, resolution=16) as env:
        env.reset()
        keyframes = env.expert_actions()
        for _ in range(4):  # approach, grasp, lift, move above the plant (upright)
            env.sim.execute(next(keyframes))
        assert not env.success()
        env.sim.execute(next(keyframes))  # tilt
        assert env.success()
        assert np.isfinite(env.sim.object_pose(env.instance.info["target"])).all()


def test_every_task_instruction_parses_to_a_skill_of_that_task():
    """The tasks' templates and the parser's skills (language/templates.yaml) cannot drift apart."""
    from abm.language import TemplateParser
    from abm.sim.splits import load_splits

    parser, splits = TemplateParser(), load_splits()
    for name, cls in TASKS.items():
        for split, objects in splits.tasks.get(name, {}).items():
            # a two-target task's second slot (put_in_container: Y) must come out as the parser's `second`
            seconds = splits.slots.get(name, {}).get("containers", {}).get(split, [None])
            for template in cls.templates:
                for obj in objects:
                    for second in seconds:
                        parsed = parser.parse(template.format(target=obj, container=second))
                        assert name in parsed.tasks, (name, split, template, parsed)
                        assert parsed.target == obj, (name, template, obj, parsed.target)
                        assert parsed.second == second, (name, template, second, parsed.second)
