"""put_in_container ("put the X in the Y", issue 14): two objects vary per episode, every split draws X
and Y from its own lists, the compositional split holds exactly the pairs kept out of training, the
expert succeeds and labels its keyframes with sub-goals (stored in the episode file), the predicate wants
X in the named container, and the instructions parse to X and Y. Cameras are rendered at 16 pixels only
where an episode is stored."""

from __future__ import annotations

import numpy as np
import pytest

from sim_helpers import require_simulator, teleport

require_simulator(libero=True)

from abm.sim.env import make_env, run_expert  # noqa: E402
from abm.sim.splits import SplitFileError, load_splits  # noqa: E402
from abm.sim.tasks import get_task  # noqa: E402
from abm.sim.tasks.put_in_container import SLOT, held_out_pairs, split_pairs  # noqa: E402
from abm.types import KeyframeAction  # noqa: E402

TASK = "put_in_container"
SPLITS = ("seen", "unseen", "compositional")
SEEDS = range(24)
SUBGOALS = [0, 0, 0, 1, 1, 1]  # approach, grasp, lift on X; move, place, retreat on Y


@pytest.fixture(scope="module")
def splits():
    return load_splits()


@pytest.fixture(scope="module")
def task(splits):
    return get_task(TASK, splits)


def _roles(inst) -> tuple[str, str, list[str], list[str]]:
    """``(X, Y, distractor containers, distractor objects)`` of a sampled scene."""
    names = [o.name for o in inst.scene.objects]
    x, y = names[inst.info["target"]], names[inst.info["container"]]
    spare = [names[i] for i in inst.info["distractor_containers"]]
    used = {inst.info["target"], inst.info["container"], *inst.info["distractor_containers"]}
    return x, y, spare, [n for i, n in enumerate(names) if i not in used]


def test_scenes_vary_in_both_objects_and_name_them_in_order(task):
    insts = [task.sample(seed, "seen") for seed in SEEDS]
    pairs = [(i.target_names[0], i.target_names[1]) for i in insts]
    assert len({x for x, _ in pairs}) >= 5 and len({y for _, y in pairs}) == 3 and len(set(pairs)) >= 10
    assert len({i.instruction.split()[0] for i in insts}) == len(task.templates)  # all templates are used
    for inst in insts:
        x, y, spare, others = _roles(inst)
        assert inst.target_names == [x, y]
        assert x in inst.instruction and inst.instruction.endswith(f" {y}")
        assert len(spare) == 1 and spare[0] != y and len(others) == 2 and x not in others
        assert task.pairs("seen")[inst.variation] == (x, y)
    again = task.sample(5, "seen")
    assert [(o.name, o.x, o.y, o.yaw) for o in again.scene.objects] == \
        [(o.name, o.x, o.y, o.yaw) for o in insts[5].scene.objects]


@pytest.mark.parametrize("split", SPLITS)
def test_every_split_draws_x_and_y_from_its_lists(task, splits, split):
    objects, containers = splits.objects(TASK, split), splits.slot_objects(TASK, SLOT, split)
    seen_anywhere = {n for t in splits.tasks.values() for n in t.get("seen", [])}
    unseen_anywhere = {n for t in splits.tasks.values() for n in t.get("unseen", [])}
    seen_containers, unseen_containers = (set(splits.slot_objects(TASK, SLOT, s)) for s in ("seen", "unseen"))
    assert not seen_containers & unseen_containers
    for seed in SEEDS:
        x, y, spare, others = _roles(task.sample(seed, split))
        assert x in objects and y in containers and set(spare) <= set(containers) and set(others) <= set(objects)
        names = {x, y, *spare, *others}
        if split == "unseen":  # nothing of the scene was ever seen in training
            assert not names & (seen_anywhere | seen_containers), (seed, names)
        else:  # the seen and compositional scenes hold only seen objects and containers
            assert not names & (unseen_anywhere | unseen_containers), (seed, names)


def test_compositional_pairs_are_the_held_out_pairs_and_never_trained(task, splits):
    objects, containers = splits.objects(TASK, "seen"), splits.slot_objects(TASK, SLOT, "seen")
    # the rule: seen object i is held out with seen container i mod len(containers)
    held = {(x, containers[i % len(containers)]) for i, x in enumerate(objects)}
    assert held_out_pairs(splits) == task.held_out() == held
    assert set(task.pairs("compositional")) == held
    assert not set(task.pairs("seen")) & held
    assert set(task.pairs("seen")) | held == {(x, y) for x in objects for y in containers}
    # every object and every container of a held-out pair is still trained (with something else)
    trained = task.pairs("seen")
    assert {x for x, _ in held} <= {x for x, _ in trained} and {y for _, y in held} <= {y for _, y in trained}
    for seed in range(100):  # sampled training scenes never show a held-out pair
        inst = task.sample(seed, "seen")
        assert tuple(inst.target_names) not in held
    comp = {tuple(task.sample(seed, "compositional").target_names) for seed in SEEDS}
    assert comp <= held and len(comp) >= 5


def _write(tmp_path, body: str):
    path = tmp_path / "splits.yaml"
    path.write_text("version: 1\ntasks:\n" + body)
    return path


@pytest.mark.parametrize(
    ("body", "match"),
    [
        ("  put_in_container:\n    seen: [butter]\n", r"needs 'containers' lists for exactly its splits \['seen'\]"),
        ("  put_in_container:\n    seen: [butter]\n    containers:\n      seen: [butter]\n",
         "containers/seen.*not of the categories this slot uses"),
        ("  put_in_container:\n    seen: [butter]\n    containers:\n      easy: [basket]\n",
         "containers has unknown split 'easy'"),
        ("  put_in_container:\n    seen: [butter]\n    unseen: [popcorn]\n    containers:\n"
         "      seen: [basket, white bowl]\n      unseen: [basket]\n", r"\['basket'\] listed as both seen and unseen"),
        ("  put_in_container:\n    seen: [butter]\n    containers:\n      seen: [gold bowl]\n",
         "unknown objects.*gold bowl"),
        ("  put_in_container:\n    seen: [butter]\n    containers:\n      seen: [basket]\n",
         "split 'seen' has no .*pair to draw"),
        ("  place_food:\n    seen: [butter]\n  put_in_container:\n    seen: [butter, red block]\n"
         "    containers:\n      seen: [plate, basket]\n",
         r"demonstrated by other tasks: butter in the plate \(place_food\)"),
        ("  pick_block:\n    seen: [red block]\n    containers:\n      seen: [basket]\n", "unknown split 'containers'"),
    ],
    ids=["missing", "category", "split", "seen-and-unseen", "unknown", "no-pair", "trained-elsewhere", "no-slot"],
)
def test_split_file_problems_with_the_container_slot_fail_clearly(tmp_path, body, match):
    path = _write(tmp_path, body)
    with pytest.raises(SplitFileError, match=match) as info:
        load_splits(path)
    assert str(path) in str(info.value)


def test_a_custom_split_file_sets_both_slots(tmp_path):
    path = _write(tmp_path, "  put_in_container:\n    unseen: [pink block, popcorn]\n    containers:\n"
                            "      unseen: [yellow plate, red basket]\n")
    splits = load_splits(path)
    assert split_pairs(splits, "unseen") == [(x, y) for x in ("pink block", "popcorn")
                                             for y in ("yellow plate", "red basket")]
    inst = get_task(TASK, splits).sample(0, "unseen")
    assert inst.target_names[0] in {"pink block", "popcorn"} and inst.target_names[1] in {"yellow plate", "red basket"}


@pytest.mark.parametrize(("split", "seed"), [(s, k) for s in SPLITS for k in (0, 3)])
def test_expert_succeeds_and_labels_subgoals(split, seed):
    with make_env(TASK, split, seed, resolution=16) as env:
        env.reset()
        assert not env.success()
        episode = run_expert(env, record=False)
    assert episode.success, episode.metadata["motions"]
    assert all(m == "reached" for m in episode.metadata["motions"])
    assert episode.metadata["subgoals"] == SUBGOALS


def test_subgoal_labels_follow_the_keyframe_kinds_and_survive_the_episode_file(tmp_path, expert_episode):
    from abm.data.episode_store import load_episode, save_episode

    episode = expert_episode(TASK, "seen", 1, 16)  # the session's rollout (read only)
    with make_env(TASK, "seen", 1, resolution=16) as env:  # the sampled instance only: no simulation is built
        targets = [env.instance.target_names[0], env.instance.target_names[1]]
    assert episode.success and episode.target_names == targets
    kinds = [a.kind for _, a in episode.steps]
    assert kinds == ["approach", "grasp", "lift", "move", "place", "retreat"]
    assert episode.metadata["subgoals"] == SUBGOALS
    save_episode(episode, tmp_path / "ep.h5")
    loaded = load_episode(tmp_path / "ep.h5")
    assert loaded.metadata["subgoals"] == SUBGOALS and loaded.target_names == episode.target_names
    assert [a.kind for _, a in loaded.steps] == kinds
    # tasks without sub-goal labels keep their metadata as it was
    action = episode.steps[0][1]
    assert get_task("place_food").keyframe_subgoal(action) is None
    assert get_task(TASK).keyframe_subgoal(KeyframeAction(np.zeros(3), np.array([0, 0, 0, 1.0]), True)) is None


def test_predicate_wants_x_resting_in_the_named_container():
    task = get_task(TASK)
    with make_env(TASK, "seen", 2, resolution=16) as env:
        env.reset()
        sim, info = env.sim, env.instance.info
        x = info["target"]
        start = sim.object_pose(x)[:3, 3].copy()
        for container, expected in ((info["distractor_containers"][0], False), (info["container"], True)):
            centre, _, _ = task.opening(sim, container)
            teleport(sim, x, [centre[0], centre[1], 0.13])  # dropped into the container's opening
            sim.step_seconds(0.8)
            assert env.success() is expected, container
        teleport(sim, x, start + [0, 0, 0.01])  # back on the table where it started
        sim.step_seconds(0.5)
        assert not env.success()


def test_instructions_parse_to_x_and_y(task, splits):
    from abm.language.instruction import TemplateParser, decompose_instruction

    parser = TemplateParser()
    for split in SPLITS:
        for x, y in task.pairs(split):
            for k in range(len(task.templates)):
                parsed = parser.parse(task.instruction_for(x, y, k))
                assert (parsed.target, parsed.second, parsed.skill) == (x, y, "put X in Y")
                assert parsed.targets == (x, y) and TASK in parsed.tasks
    inst = task.sample(4, "unseen")
    assert decompose_instruction(inst.instruction) == (inst.target_names[0], "put X in Y")
    assert parser.parse(inst.instruction).targets == tuple(inst.target_names)
