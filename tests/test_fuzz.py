"""Fuzzing the parsers and readers: random text and random bytes give the project's own errors, never
a traceback from somewhere else."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from abm.data.episode_store import EpisodeFormatError, load_episode, read_info
from abm.grounding.instruction import InstructionError, decompose_instruction
from abm.policy.checkpoint import load_checkpoint
from abm.sim.splits import SplitFileError, load_splits

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@FUZZ
@given(st.text(max_size=200))
def test_instruction_parser_never_crashes(text: str) -> None:
    try:
        target, skill = decompose_instruction(text)
    except InstructionError:
        return
    assert isinstance(target, str) and target and isinstance(skill, str) and "X" in skill


@FUZZ
@given(st.sampled_from(["put the ", "pick up the ", "stack the ", "place the "]), st.text(max_size=40),
       st.sampled_from([" in the plate", " on the target", " in the shelf", "", " onto the "]))
def test_instruction_parser_on_near_misses(prefix: str, middle: str, suffix: str) -> None:
    try:
        decompose_instruction(prefix + middle + suffix)
    except InstructionError:
        pass


@FUZZ
@given(st.binary(max_size=4096))
def test_episode_reader_refuses_random_bytes(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("ep") / "random.h5"
    path.write_bytes(data)
    with pytest.raises(EpisodeFormatError):
        load_episode(path)
    with pytest.raises(EpisodeFormatError):
        read_info(path)


@FUZZ
@given(st.one_of(st.text(max_size=300),
                 st.builds(lambda body: "version: 1\ntasks:\n" + body, st.text(max_size=200))))
def test_split_reader_refuses_random_text(tmp_path_factory, text: str) -> None:
    path = tmp_path_factory.mktemp("splits") / "splits.yaml"
    path.write_bytes(text.encode("utf-8", errors="replace"))  # hypothesis text may hold lone surrogates
    try:
        load_splits(path)
    except SplitFileError:
        pass


@FUZZ
@given(st.binary(max_size=4096))
def test_checkpoint_reader_refuses_random_bytes(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("ck") / "random.pt"
    path.write_bytes(data)
    with pytest.raises(ValueError):
        load_checkpoint(path)
