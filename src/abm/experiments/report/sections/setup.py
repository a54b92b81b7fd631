"""The ``setup`` report section: one paragraph: machines, data, CLIP, recipe, training minutes and speed, stage
times, evaluation."""

from __future__ import annotations

import json

from abm.experiments.report.context import Context
from abm.experiments.report.numbers import number
from abm.experiments.spec import Section

STAGE_ORDER = ("data", "ground", "train", "export", "eval", "diagnose")


DEFAULT_SETUP = ("machines", "recipe", "minutes", "stages", "evaluation")


def clip_sentence(ctx: Context) -> str:
    clip = ctx.layout.clip
    if clip is None:
        return ""
    meta_path = clip / "abm_clip.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    arch = (meta.get("recipe") or {}).get("arch", {}).get("vision", {})
    size = (f"a {arch.get('num_hidden_layers')}-layer, {arch.get('hidden_size')}-wide ViT at {arch.get('image_size')}² "
            if arch else "")
    return (f"CLIP: the benchmark CLIP in `{ctx.layout.show(clip)}` (`abm clip train`: {size}trained on simulator "
            "renders of every catalog object with their names, never on demonstrations; see docs/grounding.md).")


def write(ctx: Context, section: Section) -> list[str]:
    """One paragraph: the machines, data, CLIP, recipe, training minutes and speed, stage times and the
    evaluation protocol (``section.show`` picks and orders them)."""
    spec, out = ctx.spec, ctx.outcomes
    trained = [e for e in out.entries if e.get("method") != "clip"]
    recipe = next((e["recipe"] for e in trained if e.get("recipe")), None)
    parts: dict[str, str] = {}
    if out.machines:
        parts["machines"] = (f"Machine{'s' if len(out.machines) > 1 else ''} (every session that ran a stage): "
                             f"{'; '.join(out.machines)}.")
    d = spec.data
    parts["data"] = f"Data: {d.episodes} {d.split} demonstrations per task ({', '.join(d.tasks)})."
    parts["clip"] = clip_sentence(ctx)
    if recipe:
        n, t = spec.resources.trainings_at_a_time, spec.resources.threads_each
        side = (f"{number(n)} trainings at a time with {number(t)} thread{'s' if t != 1 else ''} each" if n > 1
                else f"one training at a time with {number(t)} thread{'s' if t != 1 else ''}")
        cube = f" over a {recipe['workspace_size']:g} m cube" if "workspace_size" in recipe else ""
        crop = f", a {recipe['rotation_crop']}-pixel rotation crop" if recipe.get("rotation_crop") else ""
        zoom = (f", a zoomed second stage ({recipe['zoom_resolution']}² views of a {recipe['zoom_size']:g} m cube "
                f"around the first stage's point, patch {recipe['zoom_patch_size']})" if recipe.get("zoom_size")
                else "")
        parts["recipe"] = (f"Recipe (every model): `{recipe['preset']}` preset at {recipe['resolution']}² views{cube}, "
                           f"patch {recipe['patch_size']}{zoom}{crop}, {trained[0].get('steps')} steps of batch "
                           f"{recipe['batch']}, "
                           f"{recipe['optimizer']} lr {recipe['lr']:g}, {side}.")
    if trained:
        parts["minutes"] = "Training minutes: " + ", ".join(
            f"{e.get('run', e['name'])} {e.get('train_minutes', '?')}" for e in trained) + "."
        speeds = [f"{e.get('run', e['name'])} {e['samples_per_s']:.1f}" for e in trained if e.get("samples_per_s")]
        if speeds:
            parts["speed"] = "Training samples/s: " + ", ".join(speeds) + "."
    if out.stages:
        ranked = sorted(out.stages.items(),
                        key=lambda kv: STAGE_ORDER.index(kv[0]) if kv[0] in STAGE_ORDER else len(STAGE_ORDER))
        parts["stages"] = ("Wall time per stage, every session added up (min): "
                           + ", ".join(f"{k} {v:.0f}" for k, v in ranked) + ".")
    n = max((r["episodes"] for r in ctx.cells.values()), default=0)
    reps = max((len(r["per_repeat"]) for r in ctx.cells.values()), default=0)
    show = section.show or DEFAULT_SETUP
    if n:
        where = ", evaluated from the zoo files" if spec.evaluation.from_zoo else ""
        keyframes = f", at most {spec.evaluation.max_steps} keyframes" if "keyframes" in show else ""
        parts["evaluation"] = (f"Evaluation: {n // max(reps, 1)} seeded episodes × {reps} repeats per task and "
                               f"split{keyframes}, the same scenes for every model{where}.")
    setup = [parts[item] for item in show if parts.get(item)]
    return [" ".join(setup)] if setup else []
