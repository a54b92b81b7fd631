"""Integrity end to end (issue 38, item 4): a checkpoint or model file with one changed byte is refused by every
load, in a zoo or not; a zoo index entry without a sha256, with a file outside the zoo or a size that is not a
number is one error; episode checksums cover the attributes and the cache of verified episodes notices an edit
that keeps a file's size and modification time."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import zipfile
from pathlib import Path

import pytest
import torch

from abm.cli import main as cli_main
from abm.files import check_torch_archive, load_torch_data
from abm.policy.checkpoint import load_checkpoint, save_checkpoint

h5py = pytest.importorskip("h5py")

from abm.data.episode_store import (  # noqa: E402
    VERIFIED_RECORD,
    EpisodeFormatError,
    check_episodes,
    load_episode,
    read_info,
    save_episode,
    verify_episode,
)
from abm.train.synthetic import synthetic_episodes  # noqa: E402

ZOO = Path(__file__).parents[1] / "models"


def _flip(path: Path, offset: int, out: Path) -> Path:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    out.write_bytes(bytes(data))
    return out


def _member_offsets(path: Path) -> dict[str, int]:
    """Where each zip member's data starts (after its local header)."""
    data = path.read_bytes()
    offsets = {}
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            start = info.header_offset
            name_len = int.from_bytes(data[start + 26:start + 28], "little")
            extra_len = int.from_bytes(data[start + 28:start + 30], "little")
            offsets[info.filename] = start + 30 + name_len + extra_len
    return offsets


def test_a_changed_byte_anywhere_in_a_checkpoint_is_refused_by_every_load(shared_tiny_run, tmp_path,
                                                                           cli_errors) -> None:
    (ckpt,) = sorted((shared_tiny_run / "checkpoints").glob("step_*.pt"))
    assert check_torch_archive(ckpt) is True  # abm's checkpoints carry the sha256 of their bytes
    size = ckpt.stat().st_size
    # torch itself loads a damaged tensor without a word: the reason for the check
    offsets = _member_offsets(ckpt)
    tensor = next(name for name in offsets if "/data/" in name)
    damaged = _flip(ckpt, offsets[tensor] + 1, tmp_path / "tensor.pt")
    torch.load(damaged, weights_only=True)
    # a byte of a header, of a tensor, of the central directory, of the zip's end record and of the record itself
    for offset in (2, 14, offsets[tensor] + 1, size // 2, size - 200, size - 100, size - 60, size - 1):
        bad = _flip(ckpt, offset, tmp_path / f"flip_{offset}.pt")
        with pytest.raises(ValueError, match=f"flip_{offset}.pt") as err:
            load_checkpoint(bad)
        assert "changed or damaged" in str(err.value) and "weights_only" not in str(err.value), offset
    # the same refusal through the commands that load checkpoints: export, resume, evaluation
    bad = _flip(ckpt, size // 2, tmp_path / "bad.pt")
    assert cli_main(["export", "--run", str(bad), "--out", str(tmp_path / "exported.pt")]) == 2
    (error,) = cli_errors()
    assert error.startswith(f"abm: error: {bad} does not match the sha256 recorded in it when it was written")
    assert not (tmp_path / "exported.pt").exists()
    run = tmp_path / "run"
    shutil.copytree(shared_tiny_run, run)
    shutil.copy(bad, run / "checkpoints" / ckpt.name)
    assert cli_main(["train", "--method", "abm", "--synthetic", "2", "--camera-resolution", "32", "--steps", "3",
                     "--batch", "2", "--out", str(run), "--resume", "--no-progress"]) == 2
    (error,) = cli_errors()
    assert f"{run / 'checkpoints' / ckpt.name} does not match the sha256" in error
    assert cli_main(["eval", "--run", str(bad), "--tasks", "pick_block", "--episodes", "1",
                     "--out", str(tmp_path / "eval")]) == 2
    assert any(f"{bad} does not match the sha256" in line for line in cli_errors())
    # an export is sealed too, and loads
    assert cli_main(["export", "--run", str(ckpt), "--out", str(tmp_path / "ok.pt")]) == 0
    assert check_torch_archive(tmp_path / "ok.pt") is True and load_checkpoint(tmp_path / "ok.pt")["step"] == 2


def test_a_checkpoint_without_abms_record_is_checked_member_by_member(shared_tiny_run, tmp_path) -> None:
    """Checkpoints written by torch.save directly (older abm, other tools) carry a CRC-32 per member."""
    (ckpt,) = sorted((shared_tiny_run / "checkpoints").glob("step_*.pt"))
    plain = tmp_path / "plain.pt"
    torch.save(torch.load(ckpt, weights_only=True), plain)
    assert check_torch_archive(plain) is False and load_checkpoint(plain)["step"] == 2
    offsets = _member_offsets(plain)
    tensor = next(name for name in offsets if "/data/" in name)
    bad = _flip(plain, offsets[tensor] + 3, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match=rf"bad.pt: {tensor} inside it does not match its CRC-32; the file was "
                                         r"changed or damaged"):
        load_checkpoint(bad)
    with pytest.raises(ValueError, match="bad.pt: .* does not match its CRC-32"):
        load_torch_data(bad, "abm CLIP training checkpoint")  # every torch file abm reads goes through it
    # a comment that is not abm's record (a changed byte in it, or another tool's) is refused as well
    sealed = tmp_path / "sealed.pt"
    save_checkpoint(sealed, {"step": 1})
    sealed.write_bytes(sealed.read_bytes()[:-1] + b"g")  # the record's last hex digit
    with pytest.raises(ValueError, match="sealed.pt: its zip archive comment is not abm's sha256 record"):
        load_checkpoint(sealed)


def test_a_zoo_model_is_checked_against_its_index_however_it_is_loaded(tmp_path) -> None:
    """A committed zoo model has no record of its own: the index next to it holds its sha256, which every load
    checks, so a changed byte the member CRCs do not cover (a header's time stamp) is refused too."""
    zoo = tmp_path / "models"
    zoo.mkdir()
    shutil.copy(ZOO / "abm_oracle.pt", zoo / "abm_oracle.pt")
    entry = next(e for e in json.loads((ZOO / "index.json").read_text()) if e["name"] == "abm_oracle")
    (zoo / "index.json").write_text(json.dumps([entry]))
    assert load_checkpoint(zoo / "abm_oracle.pt")["policy_config"]
    stamp = 10  # the modification time in the first member's local header: no CRC covers it
    _flip(ZOO / "abm_oracle.pt", stamp, zoo / "abm_oracle.pt")
    with pytest.raises(ValueError, match=r"abm_oracle.pt does not match the sha256 that .*index.json records for it"):
        load_checkpoint(zoo / "abm_oracle.pt")
    (zoo / "index.json").unlink()  # outside a zoo, that byte is not covered (only abm's own record covers all)
    assert load_checkpoint(zoo / "abm_oracle.pt")["policy_config"]


def _zoo_with(tmp_path: Path, **changes: object) -> Path:
    zoo = tmp_path / "zoo"
    zoo.mkdir(parents=True, exist_ok=True)
    (zoo / "m.pt").write_bytes(b"model")
    entry = {"name": "m", "file": "m.pt", "method": "abm", "size_bytes": 5,
             "sha256": hashlib.sha256(b"model").hexdigest()}
    entry.update(changes)
    (zoo / "index.json").write_text(json.dumps([{k: v for k, v in entry.items() if v is not None}]))
    return zoo


@pytest.mark.parametrize("changes, message", [
    ({"sha256": None}, r"index.json: entry 0 \(m\) has no 'sha256'; every zoo file is checked against the sha256 "
                       r"of its bytes: add it"),
    ({"sha256": "abc"}, r"entry 0 \(m\) has 'sha256' 'abc', not 64 hex digits"),
    ({"file": "../outside.pt"}, r"entry 0 \(m\): 'file' '../outside.pt' points outside the zoo folder"),
    ({"file": "/etc/passwd"}, r"entry 0 \(m\): 'file' '/etc/passwd' points outside the zoo folder"),
    ({"file": "."}, r"'file' '.' points outside the zoo folder"),
    ({"size_bytes": "2 MB"}, r"entry 0 \(m\): 'size_bytes' is '2 MB', expected a whole number >= 0: fix the entry"),
    ({"steps": 1.5}, r"'steps' is 1.5, expected a whole number"),
], ids=["no-sha256", "short-sha256", "dot-dot", "absolute", "the-zoo-itself", "size-text", "steps-real"])
def test_a_zoo_index_entry_abm_cannot_trust_is_one_error(tmp_path, cli_errors, changes, message) -> None:
    import re

    zoo = _zoo_with(tmp_path, **changes)
    assert cli_main(["zoo", "list", "--zoo", str(zoo)]) == 2
    (error,) = cli_errors()
    assert re.search(message, error), error
    assert error.startswith(f"abm: error: {zoo / 'index.json'}")


def test_a_zoo_file_reached_through_a_link_out_of_the_zoo_is_refused(tmp_path, cli_errors) -> None:
    outside = tmp_path / "elsewhere.pt"
    outside.write_bytes(b"model")
    zoo = _zoo_with(tmp_path)
    (zoo / "m.pt").unlink()
    (zoo / "m.pt").symlink_to(outside)
    assert cli_main(["zoo", "list", "--zoo", str(zoo)]) == 2
    assert "'file' 'm.pt' points outside the zoo folder" in cli_errors()[0]
    assert cli_main(["zoo", "list", "--zoo", str(_zoo_with(tmp_path / "ok"))]) == 0


# ------------------------------------------------------------------------------------------------ episodes
@pytest.fixture
def store(tmp_path) -> Path:
    data = tmp_path / "data"
    for i, episode in enumerate(synthetic_episodes(2, 32)):
        save_episode(episode, data / f"ep{i}.h5")
    return data


def _keep_time(path: Path, edit) -> None:  # noqa: ANN001 - a function that changes the file
    before = path.stat()
    edit()
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))
    assert path.stat().st_mtime_ns == before.st_mtime_ns


@pytest.mark.parametrize("key, value", [("seed", 7), ("task", "close_jar"), ("instruction", "stack the cups"),
                                        ("metadata", '{"edited": true}'), ("success", 1), ("new", 1)])
def test_episode_checksums_cover_the_attributes(store, key, value) -> None:
    path = store / "ep0.h5"
    assert verify_episode(path) is True
    with h5py.File(path, "r+") as f:
        f.attrs[key] = value
    what = "added" if key == "new" else "changed"
    with pytest.raises(EpisodeFormatError, match=rf"ep0.h5: attributes do not match their checksums \({what}: {key}\)"):
        verify_episode(path)


def test_episode_checksums_cover_the_datasets_names(store) -> None:
    path = store / "ep0.h5"
    with h5py.File(path, "r+") as f:
        f.move("actions/symmetry", "actions/symmetrx")
    with pytest.raises(EpisodeFormatError, match="changed: the names, types or shapes of its datasets"):
        verify_episode(path)


def test_an_edit_that_keeps_size_and_time_fails_verification_and_training(store, tmp_path, cli_errors,
                                                                          monkeypatch) -> None:
    import abm.data.episode_store as episode_store

    paths = sorted(store.glob("*.h5"))
    assert check_episodes(paths, store) == []
    record = json.loads((store / VERIFIED_RECORD).read_text())
    assert set(record) == {"ep0.h5", "ep1.h5"} and all(len(e["sha256"]) == 64 for e in record.values())
    calls = []
    monkeypatch.setattr(episode_store, "verify_episode", lambda p: calls.append(p) or True)
    assert check_episodes(paths, store) == [] and calls == []  # unchanged: hashed, not decoded again
    monkeypatch.undo()

    # one byte inside a compressed image, same size, modification time put back
    path = store / "ep1.h5"
    with h5py.File(path, "r") as f:
        chunk = f["observations/cameras/front/rgb"].id.get_chunk_info(0)
    _keep_time(path, lambda: _flip(path, chunk.byte_offset + chunk.size // 2, path))
    bad = check_episodes(paths, store)
    assert [p for p, _ in bad] == [path] and "observations/cameras/front/rgb" in bad[0][1]

    # an attribute changed in place, modification time put back
    other = store / "ep0.h5"

    def edit() -> None:
        with h5py.File(other, "r+") as f:
            f.attrs["seed"] = 99

    _keep_time(other, edit)
    assert read_info(other).seed == 99  # a well-typed value: only the checksum tells
    bad = dict(check_episodes(paths, store))
    assert "attributes do not match their checksums (changed: seed)" in bad[other]
    out = tmp_path / "run"
    assert cli_main(["train", "--method", "abm", "--steps", "1", "--batch", "2", "--data", str(store), "--out",
                     str(out), "--no-progress"]) == 2
    (error,) = cli_errors()
    assert "2 episode file(s) in" in error and "changed: seed" in error and not out.exists()


def test_above_the_full_check_size_the_stamp_decides(store, monkeypatch) -> None:
    import abm.data.episode_store as episode_store

    paths = sorted(store.glob("*.h5"))
    assert check_episodes(paths, store) == []
    monkeypatch.setattr(episode_store, "FULL_CHECK_BYTES", 10)
    hashed = []
    real = episode_store.sha256_file
    monkeypatch.setattr(episode_store, "sha256_file", lambda p: hashed.append(p) or real(p))
    assert check_episodes(paths, store) == [] and hashed == []  # the stamps match: nothing is read
    path = store / "ep0.h5"

    def edit() -> None:
        with h5py.File(path, "r+") as f:
            f.attrs["seed"] = 5

    _keep_time(path, edit)  # the status-change time moved: the stamp differs
    assert [p for p, _ in check_episodes(paths, store)] == [path]


@pytest.mark.parametrize("key, value, expected", [
    ("seed", "abc", "attribute 'seed' is 'abc' (text), expected a whole number"),
    ("num_keyframes", [1, 2], "attribute 'num_keyframes' is [1, 2] (an array of shape (2,)), expected a whole number"),
    ("task", 5, "attribute 'task' is 5 (a whole number), expected text"),
    ("success", 2.5, "attribute 'success' is 2.5 (a real number), expected true or false"),
    ("object_names", "[1, 2]", "attribute 'object_names' is [1, 2], expected a JSON object of object ids"),
    ("camera_names", '{"a": 1}', 'attribute \'camera_names\' is {"a": 1}, expected a JSON list of camera names'),
    ("metadata", "[1]", "attribute 'metadata' is [1], expected a JSON object"),
])
def test_an_attribute_of_the_wrong_type_is_an_error_naming_the_file(store, key, value, expected) -> None:
    path = store / "ep0.h5"
    with h5py.File(path, "r+") as f:
        f.attrs[key] = value
    with pytest.raises(EpisodeFormatError) as err:
        load_episode(path)
    assert str(err.value).startswith(f"{path}: {expected}"), str(err.value)
    assert str(err.value).endswith("(delete it and run `abm data generate` again to replace it, or import it again)")
