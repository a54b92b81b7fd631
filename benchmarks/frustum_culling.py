"""What each camera's frustum culling leaves out of a rollout's scenes; what a colour draw costs with and without it.

Usage: python benchmarks/frustum_culling.py [--task place_food] [--episodes 3] [--keyframes 4] [--draws 20]
       [--out docs/results/frustum_culling.json]

The scenes are the evaluation's (``eval_seed(0, episode)``, episodes 0..N-1, as ``benchmarks/rollout_speed.py``
rolls them out) at 128². Each scene is observed at its reset and after each of the expert's first ``--keyframes``
keyframes; for every observation and camera, :class:`abm.sim.frustum_culling.FrustumCulling` decides which mesh
geoms it leaves out (no draw needed: the shares are deterministic). Printed and written: per camera, the mesh
triangles of the scene's camera views and the share left out, and each scene's mesh triangles.

``--draws N`` also times (``time.process_time``, every thread of the process) ``N`` colour draws of the first
camera at the first scene's reset, three ways: every mesh drawn, the culled scene, no mesh at all; in the
rasterizer setting an evaluation worker uses (``LP_NUM_THREADS=0`` unless set). These are CPU milliseconds on a
shared machine: the output records the load average beside them.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import time
from pathlib import Path
from typing import Any

from abm.machine import describe_machine
from abm.sim.cameras import RASTERIZER_THREADS, single_threaded_rasterizer
from abm.sim.frustum_culling import mesh_slots


def culled_shares(task: str, episodes: int, keyframes: int) -> dict[str, Any]:
    """Per camera: mesh triangles in view of the scene's camera views and those culling leaves out, summed over
    the observations; per scene: its drawn mesh triangles."""
    from abm.evaluation.results import eval_seed
    from abm.sim.env import make_env

    cameras: dict[str, dict[str, int]] = {}
    scenes = []
    for episode in range(episodes):
        seed = eval_seed(0, episode)
        with make_env(task, "seen", seed, resolution=128) as env:
            env.reset()
            sim = env._require_sim()
            rig, culling = sim.cameras, sim.cameras.culling
            if culling is None:
                raise SystemExit(f"{task} seed {seed}: the model is not culled (reflections or shadows)")
            renderer = rig._renderer
            scene_triangles = 0
            for action in [None, *itertools.islice(env.expert_actions(), keyframes)]:
                if action is not None:
                    sim.execute(action)
                for name, cid in zip(rig.camera_names, rig.camera_ids, strict=True):
                    renderer.update_scene(sim.data, camera=cid)
                    scene = renderer._scene
                    slots = mesh_slots(scene)
                    meshes = rig.model.geom_dataid[[scene.geoms[i].objid for i in slots]]
                    total = int(rig.model.mesh_facenum[meshes].sum())
                    scene_triangles = max(scene_triangles, total)
                    counts = cameras.setdefault(name, {"triangles": 0, "culled": 0})
                    counts["triangles"] += total
                    counts["culled"] += culling.apply(renderer, sim.data)
            scenes.append({"seed": seed, "mesh_triangles": scene_triangles})
    every = {"triangles": sum(c["triangles"] for c in cameras.values()),
             "culled": sum(c["culled"] for c in cameras.values())}
    return {"cameras": {name: {**c, "culled_share": round(c["culled"] / c["triangles"], 4)}
                        for name, c in [*cameras.items(), ("all", every)]},
            "scenes": scenes}


def draw_milliseconds(task: str, draws: int) -> dict[str, float]:
    """Mean CPU ms of one colour draw (``render`` with its read-back) of the first camera at the first scene's
    reset: every mesh drawn, the culled scene, no mesh."""
    from abm.evaluation.results import eval_seed
    from abm.sim.env import make_env

    with make_env(task, "seen", eval_seed(0, 0), resolution=128) as env:
        env.reset()
        sim = env._require_sim()
        rig = sim.cameras
        renderer, cid, culling = rig._renderer, rig.camera_ids[0], rig.culling
        assert culling is not None
        activate = getattr(renderer, "activate", None)

        def timed(drawn: str) -> float:
            if activate is not None:
                activate()
            renderer.update_scene(sim.data, camera=cid)
            if drawn == "culled":
                culling.apply(renderer, sim.data)
            elif drawn == "no mesh":
                scene = renderer._scene
                for i in mesh_slots(scene):
                    scene.geoms[i].dataid = -1
            renderer.render()  # warm-up
            start = time.process_time()
            for _ in range(draws):
                renderer.render()
            return round((time.process_time() - start) / draws * 1000, 2)

        return {f"{rig.camera_names[0]}, {drawn}": timed(drawn) for drawn in ("every mesh", "culled", "no mesh")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="place_food")
    parser.add_argument("--episodes", type=int, default=3, help="scenes: eval_seed(0, episode) for 0..N-1")
    parser.add_argument("--keyframes", type=int, default=4, help="expert keyframes executed after the reset")
    parser.add_argument("--draws", type=int, default=0, help="timed colour draws per setting (0: none)")
    parser.add_argument("--out", type=Path, help="write the results as JSON here")
    args = parser.parse_args()
    single_threaded_rasterizer()
    result: dict[str, Any] = {"date": time.strftime("%Y-%m-%d"), "machine": describe_machine(), "task": args.task,
                              "split": "seen", "episodes": args.episodes, "keyframes": args.keyframes,
                              "resolution": 128, **culled_shares(args.task, args.episodes, args.keyframes)}
    for name, c in result["cameras"].items():
        print(f"{name}: {c['culled']} of {c['triangles']} mesh triangles left out ({100 * c['culled_share']:.1f} %)")
    for scene in result["scenes"]:
        print(f"seed {scene['seed']}: {scene['mesh_triangles']} mesh triangles")
    if args.draws:
        result["draws"] = args.draws
        result[RASTERIZER_THREADS] = os.environ.get(RASTERIZER_THREADS)
        result["colour_draw_cpu_ms"] = draw_milliseconds(args.task, args.draws)
        result["load_average_1min"] = round(os.getloadavg()[0], 2)
        for what, ms in result["colour_draw_cpu_ms"].items():
            print(f"colour draw, {what}: {ms:.2f} CPU ms (load average {result['load_average_1min']})")
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
