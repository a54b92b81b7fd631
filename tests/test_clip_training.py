"""The benchmark CLIP: captions, the simulator renderer, patch labels, the losses, a short training run
that must lower the loss, resuming, and the saved folder round-tripping through ``load_clip``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

pytest.importorskip("transformers")

from abm.clip_training.captions import (  # noqa: E402
    BACKGROUND_CLASSES,
    caption,
    class_names,
)
from abm.clip_training.data import (  # noqa: E402
    BACKGROUND_CROP,
    OBJECT_CROP,
    SCENE,
    ClipDataset,
    RenderConfig,
    render_world,
    square_crop_box,
)
from abm.clip_training.train import (  # noqa: E402
    CHECKPOINT,
    ClipTrainConfig,
    contrastive_loss,
    dense_vocabulary,
    encode_images,
    encode_texts,
    patch_labels,
    train,
    zero_shot_accuracy,
)
from abm.errors import OutputError  # noqa: E402

TINY_ARCH = dict(
    projection_dim=32,
    vision=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2,
                image_size=64, patch_size=16),
    text=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2, num_attention_heads=2),
)
COLOURS = {"red block": (220, 30, 30), "green block": (30, 180, 40), "blue block": (30, 60, 230),
           "yellow block": (240, 220, 30)}


def toy_dataset(n: int = 24, size: int = 64, seed: int = 0) -> ClipDataset:
    """Coloured squares on a grey table: crops captioned with the square's colour name."""
    rng = np.random.default_rng(seed)
    names = (*COLOURS, *BACKGROUND_CLASSES)
    table = names.index("table")
    images = np.full((n, size, size, 3), 128, np.uint8)
    classes = np.full((n, size, size), table, np.uint8)
    label = np.zeros(n, np.int16)
    captions = []
    for i in range(n):
        c = i % len(COLOURS)
        side = int(rng.integers(size // 3, size // 2))
        top, left = (int(v) for v in rng.integers(0, size - side, 2))
        images[i, top:top + side, left:left + side] = list(COLOURS.values())[c]
        classes[i, top:top + side, left:left + side] = c
        label[i] = c
        captions.append(caption(names[c], rng))
    return ClipDataset(images, classes, np.full(n, OBJECT_CROP, np.uint8), label, np.array(captions), names)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny CLIP trained for 60 steps on the toy set (shared by the tests below)."""
    out = tmp_path_factory.mktemp("clip") / "model"
    data = toy_dataset()
    config = ClipTrainConfig(steps=60, batch_size=12, lr=2e-3, warmup_steps=5, log_every=10, checkpoint_every=30,
                         threads=1, arch=TINY_ARCH)  # one thread: immune to a busy machine
    summary = train(data, out, config, progress=False)
    return out, data, config, summary


# ---- captions and labels ---------------------------------------------------------------------------
def test_class_names_cover_the_catalog_and_background():
    from abm.sim.catalog import CATALOG

    names = class_names()
    assert names[:len(CATALOG)] == tuple(CATALOG)
    assert names[len(CATALOG):] == BACKGROUND_CLASSES


@pytest.mark.parametrize("name", ["ketchup", "orange juice", "red block", "cyan peg", "wine bottle"])
def test_captions_name_the_object(name):
    rng = np.random.default_rng(0)
    colour, kind = name.split()[0], name.split()[-1]
    synonyms = {"block": "cube", "peg": "peg"}
    for _ in range(30):
        text = caption(name, rng)
        assert name in text or (colour in text and synonyms.get(kind, kind) in text), text
        assert len(text) < 70  # fits the 77-token context of the character tokenizer


def test_dense_vocabulary_parents():
    names = (*COLOURS, *BACKGROUND_CLASSES)
    prompts, parents = dense_vocabulary(names, len(COLOURS))
    assert prompts[0] == "a photo of a red block"
    assert prompts[len(names):] == ["a photo of an object", "a photo of a things", "a photo of a stuff",
                                    "a photo of a texture"]
    assert [prompts[p] for p in parents[:4]] == ["a photo of an object"] * 4
    assert prompts[parents[names.index("table")]] == "a photo of a texture"
    assert prompts[parents[names.index("robot arm")]] == "a photo of a things"


def test_patch_labels_prefer_small_objects_and_skip_mixed_patches():
    # classes: 0 = object, 1 = table, 2 = floor (num_objects = 1); one 16x16 image of 2x2 patches of 8 px
    cls = torch.ones(1, 16, 16, dtype=torch.uint8)
    cls[0, 0:4, 0:4] = 0            # patch (0, 0): object covers 16/64 = 25 % -> object
    cls[0, 0:2, 8:10] = 0           # patch (0, 1): object covers 4/64 = 6 % -> table
    cls[0, 8:16, 0:4] = 2           # patch (1, 0): half floor, half table -> ambiguous at 0.6 -> -1
    cls[0, 8:16, 8:16] = 2          # patch (1, 1): floor
    labels = patch_labels(cls, 8, num_classes=3, num_objects=1, object_fraction=0.2, background_fraction=0.6)
    assert labels.tolist() == [[0, 1, -1, 2]]


def test_contrastive_loss_treats_same_class_pairs_as_positives():
    # two near-identical crops (and their captions) plus a third one
    emb = torch.nn.functional.normalize(torch.tensor([[1.0, 0.1], [1.0, -0.1], [0.0, 1.0]]), dim=-1)

    def excess(labels: list[int]) -> float:
        """Loss above its minimum (the entropy of the soft targets), i.e. what training would push on."""
        lab = torch.tensor(labels)
        same = (lab[:, None] == lab[None, :]).float()
        target = same / same.sum(1, keepdim=True)
        entropy = float(-(target * target.clamp_min(1e-12).log()).sum(1).mean())
        return float(contrastive_loss(emb, emb, lab, torch.tensor(20.0))) - entropy

    # as one class the two crops are (nearly) at the optimum; as two classes they must be pushed apart
    assert excess([0, 0, 1]) < 0.05 < 0.3 < excess([0, 1, 2])


def test_square_crop_box_stays_inside_and_keeps_the_object():
    rng = np.random.default_rng(0)
    for _ in range(50):
        r0, c0 = (int(v) for v in rng.integers(0, 230, 2))
        rows, cols = np.mgrid[r0:r0 + 20, c0:c0 + 12]
        top, left, side = square_crop_box(rows.ravel(), cols.ravel(), 256, rng)
        assert 0 <= top and top + side <= 256 and 0 <= left and left + side <= 256
        assert top <= r0 + 10 < top + side and left <= c0 + 6 < left + side


# ---- the renderer ----------------------------------------------------------------------------------
def test_render_world_samples_match_their_claims():
    objects = ("red block", "ketchup", "plate")
    config = RenderConfig(image_size=64, crop_render=128, objects_per_world=3, layouts_per_world=2,
                          views_per_layout=2, crops_per_view=2, background_crop_prob=1.0, robot_prob=0.0,
                          min_crop_pixels=40, objects=objects)
    names = class_names(objects)
    samples = render_world((0, 0, 1), config, names)
    kinds = [s.kind for s in samples]
    assert kinds.count(SCENE) == 4 and kinds.count(OBJECT_CROP) >= 1 and kinds.count(BACKGROUND_CROP) >= 1
    seen_objects = set()
    for s in samples:
        assert s.image.shape == (64, 64, 3) and s.image.dtype == np.uint8 and s.classes.shape == (64, 64)
        assert s.classes.max() < len(names)
        if s.kind == SCENE:
            assert s.caption == "" and s.label == -1
            seen_objects |= {names[c] for c in np.unique(s.classes) if c < len(objects)}
            assert (s.classes == names.index("table")).mean() > 0.05  # the table is in view
        elif s.kind == OBJECT_CROP:
            name = names[s.label]
            assert name in objects
            assert name in s.caption or (name == "red block" and "red cube" in s.caption), s.caption
            assert (s.classes == s.label).mean() >= 0.04  # the crop contains the object's segmentation
        else:
            assert names[s.label] in BACKGROUND_CLASSES
            assert (s.classes < len(objects)).mean() < 0.03  # (almost) no object pixels
    assert seen_objects  # the scenes show catalog objects with their segmentation


# ---- training, resuming, saving ---------------------------------------------------------------------
def test_training_lowers_the_contrastive_and_dense_losses(trained):
    out, data, config, summary = trained
    first, final = summary["first"], summary["final"]
    assert summary["steps"] == config.steps
    assert final["contrastive"] < 0.7 * first["contrastive"]
    assert final["dense"] < 0.7 * first["dense"]
    rows = (out / "train_log.csv").read_text().splitlines()
    assert len(rows) == 1 + config.steps // config.log_every


def test_saved_folder_round_trips_through_load_clip(trained):
    from abm.clip_training.train import new_model
    from abm.grounding.clip import load_clip

    out, data, config, summary = trained
    for name in ("config.json", "model.safetensors", "preprocessor_config.json", "vocab.json", "merges.txt"):
        assert (out / name).is_file(), name
    backbone = load_clip(str(out), device="cpu")
    pre = json.loads((out / "preprocessor_config.json").read_text())
    assert backbone.image_mean == pytest.approx(tuple(pre["image_mean"]))
    assert backbone.image_mean == pytest.approx(tuple(summary["image_mean"]))
    assert backbone.image_size == 64 and backbone.grid_size == 4
    # the loaded weights are the trained ones: the checkpoint's model gives the same features
    model, tokenizer = new_model(config)
    model.load_state_dict(torch.load(out / CHECKPOINT, weights_only=False)["model"])
    model.eval()
    with torch.no_grad():
        _, dense = encode_images(model, backbone.preprocess(data.images[:3]))
        text = encode_texts(model, tokenizer, ["a photo of a red block", "a blue cube"])
    torch.testing.assert_close(backbone.dense_features(data.images[:3]).reshape(dense.shape), dense)
    torch.testing.assert_close(backbone.text_features(["a photo of a red block", "a blue cube"]), text)


def test_trained_model_classifies_and_localises_the_toy_objects(trained):
    from abm.grounding.clip import load_clip

    out, data, _, _ = trained
    backbone = load_clip(str(out), device="cpu")
    result = zero_shot_accuracy(backbone, toy_dataset(n=16, seed=5))  # held-out squares
    assert result["crops"] == 16 and result["classes"] == 4
    assert result["accuracy"] >= 0.75 and result["dense_accuracy"] >= 0.75
    # dense features: the square's patches match its name better than the table's patches do
    test = toy_dataset(n=8, seed=7)
    feats = backbone.dense_features(test.images).numpy()                       # (8, 4, 4, D)
    text = backbone.text_features([f"a photo of a {n}" for n in COLOURS]).numpy()
    inside = []
    for i in range(len(test)):
        cells = test.classes[i].reshape(4, 16, 4, 16).transpose(0, 2, 1, 3).reshape(4, 4, -1)
        object_share = (cells == test.label[i]).mean(-1)
        sim = feats[i] @ text[test.label[i]]
        inside.append(sim.ravel()[object_share.argmax()] > sim[object_share == 0].mean())
    assert np.mean(inside) >= 0.75


def test_resume_continues_and_a_new_run_refuses_to_overwrite(trained, tmp_path):
    out, data, config, _ = trained
    with pytest.raises(OutputError, match="pass --resume"):
        train(data, out, config, progress=False)
    copy = tmp_path / "copy"
    copy.mkdir()
    for f in out.iterdir():
        (copy / f.name).write_bytes(f.read_bytes())
    more = ClipTrainConfig(**{**config.__dict__, "steps": config.steps + 10})
    summary = train(data, copy, more, resume=True, progress=False)
    assert summary["steps"] == config.steps + 10
    assert len((copy / "train_log.csv").read_text().splitlines()) == 1 + (config.steps + 10) // config.log_every


def test_cli_registers_clip_train():
    from abm.cli import build_parser, command_function
    from abm.cli.commands.clip import run_train

    args = build_parser().parse_args(["clip", "train", "--out", "x", "--steps", "5", "--resume"])
    assert command_function(args.func) is run_train and args.steps == 5 and args.resume and args.shards > 0


def test_cli_refuses_to_overwrite_a_run(tmp_path, capsys):
    from abm.cli import main

    (tmp_path / CHECKPOINT).write_bytes(b"")
    assert main(["clip", "train", "--out", str(tmp_path), "--shards", "1"]) == 2
    assert "--resume" in capsys.readouterr().err
    assert not (tmp_path / "data").exists()  # refused before rendering anything
