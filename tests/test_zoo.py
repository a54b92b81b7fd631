"""``abm zoo``: the index is read and every file verified against its sha256; the entries compared are chosen
by what the zoo holds."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from abm.cli import main
from abm.zoo import ZooError, named, pick, read_index, verify


def _zoo(tmp_path: Path, names: tuple[str, ...] = ("abm_oracle", "rvt_clip")) -> Path:
    zoo = tmp_path / "models"
    zoo.mkdir(parents=True)
    entries = []
    for name in names:
        data = name.encode()
        (zoo / f"{name}.pt").write_bytes(data)
        kind = "oracle" if name == "abm_oracle" else "clip"
        entries.append({"name": name, "file": f"{name}.pt", "method": name.split("_")[0], "grounder": kind,
                        "grounder_spec": {"kind": kind}, "size_bytes": len(data),
                        "sha256": hashlib.sha256(data).hexdigest()})
    (zoo / "index.json").write_text(json.dumps(entries))
    return zoo


def test_list_verifies_every_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    zoo = _zoo(tmp_path)
    assert main(["zoo", "list", "--zoo", str(zoo)]) == 0
    out = capsys.readouterr().out
    assert "abm_oracle" in out and "rvt_clip" in out and "FAILED" not in out
    (zoo / "rvt_clip.pt").write_bytes(b"changed")
    assert main(["zoo", "list", "--zoo", str(zoo)]) == 2
    captured = capsys.readouterr()
    assert "rvt_clip.pt does not match its recorded sha256" in captured.out
    assert "abm: error: 1 zoo file(s) failed verification" in captured.err


def test_list_columns_line_up_for_long_names(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    long = "concat-rerendered_seed1_v2_with_a_long_name"  # longer than any fixed column width
    assert main(["zoo", "list", "--zoo", str(_zoo(tmp_path, ("abm_oracle", long, "rvt_clip")))]) == 0
    header, *rows = capsys.readouterr().out.splitlines()
    assert [r.split()[0] for r in rows] == ["abm_oracle", long, "rvt_clip"]
    for column in ("method", "grounder", "check"):  # left-aligned: every cell starts under its heading
        start = header.index(column)
        assert all(r[start - 1] == " " and r[start] != " " for r in rows), (column, rows)
    end = header.index("MB") + len("MB")  # right-aligned: every number ends under its heading
    assert all(r[end - 1] != " " and r[end] == " " for r in rows), rows
    assert all(r[header.index("check"):] == "ok" for r in rows)


def test_missing_or_malformed_index_is_one_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["zoo", "list", "--zoo", str(tmp_path / "nowhere")]) == 2
    assert "no model zoo index" in capsys.readouterr().err
    (tmp_path / "index.json").write_text("{not json")
    with pytest.raises(ZooError, match="not valid JSON"):
        read_index(tmp_path)
    (tmp_path / "index.json").write_text(json.dumps({"name": "x"}))
    with pytest.raises(ZooError, match="must be a list"):
        read_index(tmp_path)
    zoo = _zoo(tmp_path / "z")
    (zoo / "abm_oracle.pt").unlink()
    with pytest.raises(ZooError, match="listed in .* but missing"):
        verify(zoo, read_index(zoo)[0])


def test_pick_needs_the_clip_of_clip_models(tmp_path: Path) -> None:
    entries = read_index(_zoo(tmp_path, ("abm_oracle", "abm_clip", "rvt_clip")))
    # without the benchmark CLIP in the zoo, the CLIP-grounded models cannot run: fall back to the oracle row
    assert pick(entries, "abm")["name"] == "abm_oracle"
    assert pick(entries, "rvt") is None
    entries.append({"name": "benchmark-clip", "file": "benchmark-clip/", "method": "clip"})
    # with it, the CLIP-grounded abm model comes first although the index lists the oracle one before it
    assert pick(entries, "abm")["name"] == "abm_clip"
    assert pick(entries, "rvt")["name"] == "rvt_clip"
    assert pick(entries, "ifd") is None


def test_pick_takes_the_newest_editions_compared_model_and_falls_back_to_the_first(tmp_path: Path) -> None:
    entries = read_index(_zoo(tmp_path, ("abm_oracle", "abm_clip", "rvt_clip")))
    entries.append({"name": "benchmark-clip", "file": "benchmark-clip/", "method": "clip"})

    def later(name: str, method: str, number: int, compared: bool) -> dict:
        return {"name": f"{name}_v{number}", "method": method, "grounder": "clip", "grounder_spec": {"kind": "clip"},
                "edition": number, "compared": compared}

    # a second edition without its compared abm model yet: the first edition's abm_clip, not the new abm_clip_hash
    entries.append(later("abm_clip_hash", "abm", 2, False))
    assert pick(entries, "abm")["name"] == "abm_clip"
    entries += [later("abm_clip", "abm", 2, True), later("rvt_clip", "rvt", 2, True)]
    assert pick(entries, "abm")["name"] == "abm_clip_v2" and pick(entries, "rvt")["name"] == "rvt_clip_v2"
    entries.insert(0, later("abm_clip", "abm", 3, True))  # the newest edition wins wherever it stands
    assert pick(entries, "abm")["name"] == "abm_clip_v3"
    # without the benchmark CLIP none of the CLIP models can run: the first edition's oracle model
    assert pick([e for e in entries if e["name"] != "benchmark-clip"], "abm")["name"] == "abm_oracle"


def test_models_named_are_taken_in_order_whatever_pick_would_take(tmp_path: Path) -> None:
    entries = read_index(_zoo(tmp_path, ("abm_oracle", "abm_clip", "rvt_clip")))
    assert [e["name"] for e in named(entries, ["abm_oracle"])] == ["abm_oracle"]  # needs no CLIP
    with pytest.raises(ZooError, match="abm_clip grounds or words its instruction with the benchmark CLIP, which the "
                                       "zoo does not hold"):
        named(entries, ["abm_clip"])
    entries.append({"name": "benchmark-clip", "file": "benchmark-clip/", "method": "clip"})
    assert [e["name"] for e in named(entries, ("rvt_clip", "abm_oracle"))] == ["rvt_clip", "abm_oracle"]
    with pytest.raises(ZooError, match=r"'abm_clip_v9' is no model of the zoo's index \(it lists abm_oracle, "
                                       r"abm_clip, rvt_clip\)"):
        named(entries, ["abm_clip", "abm_clip_v9"])
    with pytest.raises(ZooError, match="'benchmark-clip' is no model"):
        named(entries, ["benchmark-clip"])


def test_zoo_eval_with_an_unknown_model_is_one_clear_error(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    zoo = _zoo(tmp_path)
    assert main(["zoo", "eval", "--zoo", str(zoo), "--models", "abm_clip_v3", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "'abm_clip_v3' is no model of the zoo's index (it lists abm_oracle, rvt_clip)" in err
    assert not (tmp_path / "out").exists()


def test_an_edition_that_is_not_a_whole_number_is_refused(tmp_path: Path) -> None:
    zoo = _zoo(tmp_path)
    entries = json.loads((zoo / "index.json").read_text())
    entries[0]["edition"] = "2"
    (zoo / "index.json").write_text(json.dumps(entries))
    with pytest.raises(ZooError, match="'edition' is '2', expected a whole number"):
        read_index(zoo)


def test_every_committed_zoo_file_is_the_model_its_index_records() -> None:
    """What a fresh clone's ``abm zoo eval`` and every load check: caught here, a commit that holds
    another file in place of a model's weights does not wait for a load to fail."""
    zoo = Path(__file__).parents[1] / "models"
    entries = read_index(zoo)
    assert len(entries) >= 10
    for entry in entries:
        path = verify(zoo, entry)
        size = (path / "model.safetensors" if path.is_dir() else path).stat().st_size
        assert size == entry["size_bytes"], entry["name"]
