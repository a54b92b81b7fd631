"""No file outside what the user named is ever touched, and no data is replaced without ``--overwrite``.

Each case puts a *victim* where a careless command would write or delete (a user's file in the export folder,
a file an imported episode names with ``..``, the target of a link in a run folder, the current folder for
``--out ''``) and checks the command refuses with one ``abm: error:`` line naming the path and the fix, and
the victim is unchanged. Also: the export and the import check the data they carry, an interrupted import
is marked and refused by ``abm train`` and ``abm data info``, and ``--resume`` / ``--val-data`` cannot mix
data sets.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from pathlib import Path

import pytest

pytest.importorskip("h5py")
pytest.importorskip("av")
pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

import abm.data.lerobot as lerobot  # noqa: E402
import abm.data.lerobot_export as lerobot_export  # noqa: E402
import abm.data.lerobot_import as lerobot_import  # noqa: E402
from abm.cli import build_parser  # noqa: E402
from abm.cli import main as cli_main  # noqa: E402
from abm.cli.commands.robot import check_record_target  # noqa: E402
from abm.data.episode_store import (  # noqa: E402
    IMPORT_MARKER,
    EpisodeStore,
    IncompleteStoreError,
    held_out_overlap,
    save_episode,
)
from abm.errors import OutputError  # noqa: E402
from abm.files import FolderLock, LinkError, sha256_file  # noqa: E402
from abm.policy.checkpoint import list_checkpoints  # noqa: E402
from abm.train.config import TrainConfig  # noqa: E402
from abm.train.loop import _check_same_data  # noqa: E402
from test_lerobot import make_episode  # noqa: E402

PRECIOUS = b"the user's own bytes\n"

Victim = Callable[[Path], Path]


@pytest.fixture
def victim() -> Victim:
    """``victim(path)``: a file holding :data:`PRECIOUS` (parents created); check it with :func:`untouched`."""

    def make(path: Path) -> Path:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(PRECIOUS)
        return path

    return make


def untouched(path: Path) -> bool:
    """The victim is still a regular file holding exactly :data:`PRECIOUS`."""
    return path.is_file() and not path.is_symlink() and path.read_bytes() == PRECIOUS


def _store(root: Path, seeds: tuple[int, ...] = (0, 1)) -> Path:
    for s in seeds:
        save_episode(make_episode(s), root / "pick_block" / "seen" / f"episode_{s:06d}.h5")
    return root


def _export(tmp_path: Path) -> Path:
    data = _store(tmp_path / "data")
    ds = tmp_path / "ds"
    assert cli_main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(ds)]) == 0
    return ds


def _edit_episodes(ds: Path, edit: Callable[[dict], None], row: int = 0) -> None:
    """Change the ``abm/episode`` metadata of one episode row and record the new file's sha256 in info.json, as
    someone editing (or crafting) a dataset would: the checksums then agree, and the import's own checks must
    catch it."""
    path = ds / lerobot.EPISODES_FILE
    rows = pq.read_table(path).to_pylist()
    meta = json.loads(rows[row]["abm/episode"])
    edit(meta)
    rows[row]["abm/episode"] = json.dumps(meta)
    pq.write_table(pa.Table.from_pylist(rows), path)
    info_path = ds / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["abm"]["sha256"][lerobot.EPISODES_FILE] = sha256_file(path)
    info_path.write_text(json.dumps(info))


def _import(ds: Path, out: Path, *extra: str) -> int:
    return cli_main(["data", "import", "--format", "lerobot", str(ds), "--out", str(out), *extra])


def _one_error(cli_errors: Callable[[], list[str]], *words: str) -> str:
    errors = cli_errors()
    assert len(errors) == 1, errors
    assert all(w in errors[0] for w in words), (words, errors[0])
    return errors[0]


# ---------------------------------------------------------------------------------------------- export


def test_export_onto_a_folder_with_an_old_marker_deletes_nothing(tmp_path, victim, cli_errors) -> None:
    data = _store(tmp_path / "data")
    out = tmp_path / "mine"
    mine = victim(out / "notes.txt")
    (out / lerobot.EXPORT_MARKER).write_text("left by a killed export\n")
    assert cli_main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(out)]) == 2
    _one_error(cli_errors, str(out), "did not finish", "delete that folder yourself", "new folder")
    assert untouched(mine) and (out / lerobot.EXPORT_MARKER).is_file()


def test_a_failed_export_removes_only_what_it_created(tmp_path, victim, monkeypatch, capsys, cli_errors) -> None:
    data = _store(tmp_path / "data")
    empty = tmp_path / "empty"
    empty.mkdir()
    neighbour = victim(tmp_path / "neighbour.txt")

    raised: list[Exception] = [OutputError("the disk went away")]

    def fail(path: Path, tasks: dict) -> None:  # late in the export, once a user's file appeared in the folder
        victim(path.parents[1] / "arrived_meanwhile.txt")
        raise raised[0]

    monkeypatch.setattr(lerobot_export, "_write_tasks", fail)
    assert cli_main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(empty)]) == 2
    _one_error(cli_errors, "the disk went away")
    assert sorted(p.name for p in empty.iterdir()) == ["arrived_meanwhile.txt"]  # the export's own files went
    assert untouched(empty / "arrived_meanwhile.txt") and untouched(neighbour)
    nested = tmp_path / "new" / "deeper" / "ds"
    assert cli_main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(nested)]) == 2
    cli_errors()
    assert not (tmp_path / "new").exists()  # the folders it created went too
    raised[0] = RuntimeError("a bug late in the export")  # a traceback (exit code 1), and the same clean-up
    (empty / "arrived_meanwhile.txt").unlink()
    assert cli_main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(empty)]) == 1
    assert "RuntimeError: a bug late in the export" in capsys.readouterr().err
    assert sorted(p.name for p in empty.iterdir()) == ["arrived_meanwhile.txt"]


def test_export_checks_the_episode_checksums_before_writing(tmp_path, cli_errors) -> None:
    import h5py

    data = _store(tmp_path / "data")
    bad = data / "pick_block" / "seen" / "episode_000001.h5"
    with h5py.File(bad, "r+") as f:  # a changed value whose stored CRC-32 no longer matches
        f["actions/position"][0, 0] += 1.0
    out = tmp_path / "ds"
    assert cli_main(["data", "export", "--format", "lerobot", "--data", str(data), "--out", str(out)]) == 2
    _one_error(cli_errors, "1 episode file(s) in", "episode_000001.h5", "nothing was exported", "abm data generate")
    assert not out.exists()


# ---------------------------------------------------------------------------------------------- import


@pytest.mark.parametrize("source", ["../../victim.h5", "pick_block/../../../victim.h5", "ABSOLUTE"])
def test_import_never_writes_outside_out(tmp_path, victim, cli_errors, source) -> None:
    ds = _export(tmp_path)
    target = victim(tmp_path / "victim.h5")
    name = str(target) if source == "ABSOLUTE" else source
    _edit_episodes(ds, lambda meta: meta.update(source=name))
    out = tmp_path / "x" / "out"
    for extra in ((), ("--overwrite",)):
        assert _import(ds, out, *extra) == 2
        _one_error(cli_errors, repr(name), f"outside --out {out}", "nothing was imported")
    assert untouched(target) and not out.exists()


def test_import_does_not_follow_a_link_inside_out(tmp_path, victim, cli_errors) -> None:
    ds = _export(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    target = victim(elsewhere / "seen" / "episode_000000.h5")
    out = tmp_path / "out"
    out.mkdir()
    (out / "pick_block").symlink_to(elsewhere, target_is_directory=True)
    assert _import(ds, out, "--overwrite") == 2
    _one_error(cli_errors, "outside --out")
    assert untouched(target)


@pytest.mark.parametrize("change, words", [
    ({"success": False}, ["marked failed", "only successful demonstrations"]),
    ({"task": "no_such_task"}, ["task 'no_such_task'", "known: "]),
    ({"task": "../../etc"}, ["task '../../etc'"]),
    ({"split": "elsewhere"}, ["split 'elsewhere'"]),
])
def test_import_refuses_failed_episodes_and_unknown_tasks(tmp_path, cli_errors, change, words) -> None:
    ds = _export(tmp_path)
    _edit_episodes(ds, lambda meta: meta.update(change), row=1)
    out = tmp_path / "out"
    assert _import(ds, out) == 2
    _one_error(cli_errors, "episode row 1", *words)
    assert not out.exists()  # checked before anything was written


def test_import_onto_an_existing_store_needs_overwrite(tmp_path, cli_errors) -> None:
    ds = _export(tmp_path)
    out = tmp_path / "out"
    assert _import(ds, out) == 0
    episode = out / "pick_block" / "seen" / "episode_000000.h5"
    before = (episode.read_bytes(), episode.stat().st_mtime_ns)
    assert _import(ds, out) == 2
    _one_error(cli_errors, f"--out {out} already holds 2 of the dataset's episodes", "--overwrite")
    assert (episode.read_bytes(), episode.stat().st_mtime_ns) == before
    assert _import(ds, out, "--overwrite") == 0


def test_an_interrupted_import_is_marked_and_refused_until_redone(tmp_path, monkeypatch, tiny_sets,
                                                                  cli_errors) -> None:
    ds = _export(tmp_path)
    out = tmp_path / "out"
    real_save = lerobot_import.save_episode
    calls: list[Path] = []

    def save_then_stop(episode, path) -> None:  # Ctrl-C after the first episode is written
        real_save(episode, path)
        calls.append(Path(path))
        raise KeyboardInterrupt

    monkeypatch.setattr(lerobot_import, "save_episode", save_then_stop)
    assert _import(ds, out) == 130
    monkeypatch.setattr(lerobot_import, "save_episode", real_save)
    assert len(calls) == 1 and (out / IMPORT_MARKER).is_file()
    assert "--overwrite" in (out / IMPORT_MARKER).read_text().splitlines()[0]

    for folder in (out, out / "pick_block"):  # the folder and a folder inside it
        assert cli_main(["data", "info", "--quick", str(folder)]) == 2
        _one_error(cli_errors, str(out), "did not finish", "abm data import --format lerobot", "--overwrite")
    run = tmp_path / "run"
    assert cli_main(["train", "--method", "abm", "--data", str(out), "--steps", "2", "--batch", "2", "--no-progress",
                     "--out", str(run), *tiny_sets]) == 2
    _one_error(cli_errors, "did not finish", "--overwrite")
    assert not run.exists()
    with pytest.raises(IncompleteStoreError):
        EpisodeStore(out)

    assert _import(ds, out) == 2  # finishing it replaces what it wrote: asked for explicitly
    _one_error(cli_errors, "did not finish", "--overwrite")
    assert _import(ds, out, "--overwrite") == 0
    assert not (out / IMPORT_MARKER).exists() and len(EpisodeStore(out)) == 2
    assert cli_main(["data", "info", str(out)]) == 0


# ---------------------------------------------------------------------------------------------- record


def test_record_refuses_an_existing_folder(tmp_path, victim, cli_errors) -> None:
    out = tmp_path / "rec"
    notes = victim(out / "notes.txt")
    assert cli_main(["record", "--out", str(out)]) == 2
    _one_error(cli_errors, f"--out {out} already holds other files", "--overwrite")
    step = victim(out / "step_000.npz")
    assert cli_main(["record", "--out", str(out)]) == 2
    _one_error(cli_errors, "already holds a recording", "--overwrite")
    assert untouched(notes) and untouched(step)
    assert check_record_target(out, overwrite=True) == [step]  # what --overwrite replaces: the recording only

    target = victim(tmp_path / "victim.json")
    (out / "meta.json").symlink_to(target)
    assert cli_main(["record", "--out", str(out), "--overwrite"]) == 2
    _one_error(cli_errors, str(out / "meta.json"), "symbolic link", "remove the link")
    assert untouched(target)


# ---------------------------------------------------------------------------------------------- train


def _resume_args(run: Path, *extra: str) -> list[str]:
    from conftest import TINY_POLICY

    return ["train", "--method", "abm", "--synthetic", "2", "--camera-resolution", "32", "--steps", "4", "--batch",
            "2", "--lr", "3e-3", "--warmup", "1", "--no-progress", "--out", str(run), "--resume",
            *[f"--set={k}={v}" for k, v in TINY_POLICY.items()], *extra]


@pytest.mark.parametrize("entry", [".abm.lock", "log.csv", "recipe.yaml", "tb"])
def test_train_never_writes_through_a_link_in_the_run_folder(tiny_run, tmp_path, victim, cli_errors, entry) -> None:
    target = victim(tmp_path / "victim.txt")
    link = tiny_run / entry
    if link.is_dir():
        import shutil

        shutil.rmtree(link)
    link.unlink(missing_ok=True)
    link.symlink_to(target)
    before = [s for s, _ in list_checkpoints(tiny_run)]
    assert cli_main(_resume_args(tiny_run)) == 2
    _one_error(cli_errors, str(link), "symbolic link", "remove the link")
    assert untouched(target) and link.is_symlink()
    assert [s for s, _ in list_checkpoints(tiny_run)] == before


def test_folder_lock_refuses_a_link(tmp_path, victim) -> None:
    target = victim(tmp_path / "victim.txt")
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / ".abm.lock").symlink_to(target)
    with pytest.raises(LinkError, match=r"\.abm\.lock is a symbolic link .*remove the link"):
        FolderLock(folder, "abm train").__enter__()
    assert untouched(target)


def test_resume_refuses_other_data(tiny_run, tmp_path, monkeypatch, cli_errors) -> None:
    data = _store(tmp_path / "data")
    args = _resume_args(tiny_run)
    i = args.index("--synthetic")
    args[i: i + 2] = ["--data", str(data)]
    assert cli_main(args) == 2
    _one_error(cli_errors, f"{tiny_run} was trained on in-memory episodes", f"not on --data {data}",
               "resume with the same --data")
    a, b = _store(tmp_path / "a", (0,)), tmp_path / "b"
    with pytest.raises(ValueError, match=r"trained on --data .*/a; --resume continues .* not on --data .*/b"):
        _check_same_data(tiny_run, {"data": str(a)}, TrainConfig(data=b))
    monkeypatch.chdir(tmp_path)
    _check_same_data(tiny_run, {"data": str(a)}, TrainConfig(data=Path("a")))  # the same folder, spelt otherwise


def test_val_data_must_be_held_out(tmp_path, tiny_sets, cli_errors) -> None:
    data = _store(tmp_path / "data")
    copy = _store(tmp_path / "copy")  # the same scenes (seeds) generated again into another folder
    linked = tmp_path / "linked" / "pick_block" / "seen"
    linked.mkdir(parents=True)
    os.link(data / "pick_block" / "seen" / "episode_000000.h5", linked / "other_name.h5")
    held_out = _store(tmp_path / "held_out", (7, 8))
    run = tmp_path / "run"
    cases = {data: "is the same folder as --data", data / "pick_block": "is inside --data",
             copy: "holds episodes of the same scenes", tmp_path / "linked": "holds the same episode files"}
    for val, words in cases.items():
        assert cli_main(["train", "--method", "abm", "--data", str(data), "--val-data", str(val), "--steps", "2",
                         "--out", str(run), *tiny_sets]) == 2
        _one_error(cli_errors, f"--val-data {val}", words, "held out", "--seed")
    assert not run.exists()
    assert held_out_overlap(tmp_path / "data" / "pick_block", data) is not None  # --data inside --val-data
    assert held_out_overlap(data, held_out) is None


def test_a_recipe_cannot_switch_on_overwrite(tiny_run, tmp_path, capsys) -> None:
    before = [(s, p.stat().st_mtime_ns) for s, p in list_checkpoints(tiny_run)]
    for text, words in (("overwrite: true\n", "'overwrite' cannot be set in a recipe"),
                        ("out: ''\n", "out is an empty path")):
        recipe = tmp_path / "recipe.yaml"
        recipe.write_text(text + "steps: 2\n")
        with pytest.raises(SystemExit) as done:
            cli_main(["train", "--config", str(recipe), "--method", "abm", "--synthetic", "2", "--out",
                      str(tiny_run)])
        err = capsys.readouterr().err
        assert done.value.code == 2 and err.count("abm: error:") == 1 and words in err and str(recipe) in err
    assert [(s, p.stat().st_mtime_ns) for s, p in list_checkpoints(tiny_run)] == before


# ---------------------------------------------------------------------------------------------- --out ''


def _commands_with_out() -> list[list[str]]:
    """The words of every (sub-)command that has an ``--out`` option."""
    found = []

    def walk(parser: argparse.ArgumentParser, words: list[str]) -> None:
        if "--out" in parser._option_string_actions:
            found.append(words)
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, [*words, name])

    walk(build_parser(), [])
    return found


def test_an_empty_out_is_refused_by_every_command(tmp_path, victim, monkeypatch, capsys) -> None:
    commands = _commands_with_out()
    assert {"train", "export", "record"} <= {c[0] for c in commands} and ["data", "import"] in commands
    monkeypatch.chdir(tmp_path)
    mine = victim(tmp_path / "victim.txt")
    for words in commands:
        for empty in ("", " "):
            with pytest.raises(SystemExit) as done:
                cli_main([*words, "--out", empty])
            err = capsys.readouterr().err
            assert done.value.code == 2, words
            assert err.startswith("abm: error: argument --out: expected a path, got an empty string"), (words, err)
    assert untouched(mine) and [p.name for p in tmp_path.iterdir()] == ["victim.txt"]
