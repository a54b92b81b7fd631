"""What makes a rollout's drawing cheaper changes no pixel: each camera leaves out the mesh geoms outside its view
(:mod:`abm.sim.frustum_culling`), and an evaluation rollout's process rasterizes in its drawing thread
(``LP_NUM_THREADS=0``, :func:`abm.sim.cameras.single_threaded_rasterizer`) unless the user chose otherwise.
"""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sim_helpers import require_simulator

require_simulator()

import mujoco  # noqa: E402

from abm.sim.cameras import RASTERIZER_THREADS, CameraRig  # noqa: E402
from abm.sim.env import make_env  # noqa: E402
from abm.sim.frustum_culling import FrustumCulling  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _frames(rig: CameraRig, data: mujoco.MjData) -> dict[str, tuple[np.ndarray, ...]]:
    """Each camera's colour, depth and segmentation (the rigs here draw it)."""
    frames = rig.render(data)
    assert all(f.segmentation is not None for f in frames.values())
    return {name: (f.rgb, f.depth, np.asarray(f.segmentation)) for name, f in frames.items()}


def _same(a: dict[str, tuple[np.ndarray, ...]], b: dict[str, tuple[np.ndarray, ...]]) -> None:
    for name in a:
        for x, y, what in zip(a[name], b[name], ("rgb", "depth", "segmentation"), strict=True):
            assert np.array_equal(x, y), (name, what)


@pytest.mark.parametrize(("task", "seed"), [("place_food", 3), ("put_in_shelf", 2), ("close_jar", 5)])
def test_culled_cameras_draw_every_pixel_as_all_geoms_do(task: str, seed: int) -> None:
    """At the evaluation's 128² along the expert's first keyframes (the arm moves, the wrist camera with it)."""
    with make_env(task, "seen", seed, resolution=128) as env:
        env.reset()
        sim = env._require_sim()
        rig = sim.cameras
        culling = rig.culling
        assert culling is not None  # the benchmark's scenes neither reflect nor cast shadows
        for action in [None, *itertools.islice(env.expert_actions(), 2)]:
            if action is not None:
                sim.execute(action)
            before = culling.triangles_culled
            culled = _frames(rig, sim.data)
            assert culling.triangles_culled > before  # the wrist camera, at least, does not see the whole arm
            rig.culling = None
            _same(culled, _frames(rig, sim.data))
            rig.culling = culling


MJCF = """
<mujoco>
  <visual><quality shadowsize="{shadowsize}"/></visual>
  <asset>
    <mesh name="cube" vertex="-1 -1 -1  1 -1 -1  -1 1 -1  1 1 -1  -1 -1 1  1 -1 1  -1 1 1  1 1 1" scale=".1 .1 .1"/>
    <material name="floor" reflectance="{reflectance}"/>
  </asset>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1" castshadow="{castshadow}"/>
    <geom name="floor" type="plane" size="2 2 .1" material="floor"/>
    <camera name="eye" pos="0 0 2" xyaxes="1 0 0 0 1 0" fovy="40"/>
    <camera name="sensor" pos="0 0 2" xyaxes="1 0 0 0 1 0" sensorsize=".02 .01" resolution="64 64"
            focal="{focal} {focal}"/>
    <geom name="seen" type="mesh" mesh="cube" pos="0 0 .5" rgba="1 0 0 1"/>
    <geom name="edge" type="mesh" mesh="cube" pos="{edge} 0 .5" rgba="0 1 0 1"/>
    <geom name="wide" type="mesh" mesh="cube" pos="-.9 0 .5" rgba="1 0 1 1"/>
    <geom name="aside" type="mesh" mesh="cube" pos="1.5 0 .5" rgba="0 0 1 1"/>
    <geom name="behind" type="mesh" mesh="cube" pos="0 0 2.5" rgba="1 1 0 1"/>
  </worldbody>
</mujoco>
"""
# Both cameras look straight down from 2 m at the cubes (half-size 0.1 m, centres 1.5 m deep). "eye" sees
# tan(20 deg) * width / height of the depth to either side; "sensor" (a 2:1 sensor at this focal length) sees
# 2 * tan(20 deg) whatever the picture's size. "wide" (x = -0.9) is in view only where that tangent is 2 * tan(20).
TAN_20 = float(np.tan(np.radians(20)))
SENSOR_FOCAL_M = 0.005 / TAN_20  # the sensor's half-height over its focal length is tan(20 deg)
HALF, DEPTH = 0.1, 1.5
EDGE_INSIDE_M = 0.002


def _edge_x(tangent: float) -> float:
    """Where the edge cube's centre goes for its deepest corner (x - 0.1 m, 1.6 m deep) to lie 2 mm inside the
    frustum's right side of half-angle ``atan(tangent)``."""
    return HALF + tangent * (DEPTH + HALF) - EDGE_INSIDE_M * float(np.hypot(1.0, tangent))


def _toy(reflectance: float = 0.0, shadows: bool = False, edge_x: float = 0.5) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(MJCF.format(
        reflectance=reflectance, castshadow=str(shadows).lower(), shadowsize=1024 if shadows else 0, edge=edge_x,
        focal=SENSOR_FOCAL_M))


@pytest.mark.parametrize(("camera", "height", "width", "tangent", "wide_seen"), [
    ("eye", 64, 64, TAN_20, False),
    ("eye", 48, 96, 2 * TAN_20, True),  # twice as wide as high: a width / height swap culls "edge" and "wide"
    ("sensor", 64, 64, 2 * TAN_20, True),  # its frustum_width, not the picture's aspect, sets its width
])
def test_only_the_geoms_outside_the_view_are_left_out_and_the_picture_is_the_same(
        camera: str, height: int, width: int, tangent: float, wide_seen: bool) -> None:
    model = _toy(edge_x=_edge_x(tangent))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geom_to_object = np.arange(model.ngeom, dtype=np.int32)
    rig = CameraRig(model, [camera], height, width, geom_to_object)
    try:
        assert rig.culling is not None
        culled = _frames(rig, data)
        scene = rig._renderer._scene
        left_out = {model.geom(g.objid).name for g in scene.geoms[:scene.ngeom] if g.dataid == -1}
        expected = {"aside", "behind"} | (set() if wide_seen else {"wide"})
        assert left_out == expected  # "edge" kept: 2 mm of its box are in view
        assert rig.culling.triangles_culled == 12 * len(expected)  # cubes of 12 triangles
        rig.culling = None
        drawn = _frames(rig, data)
        _same(culled, drawn)
        shown = set(np.unique(drawn[camera][2]).tolist())
        assert {model.geom("floor").id, model.geom("seen").id} <= shown
        assert (model.geom("wide").id in shown) == wide_seen
    finally:
        rig.close()


def test_models_that_show_what_is_outside_the_view_are_not_culled() -> None:
    assert FrustumCulling.for_model(_toy()) is not None
    assert FrustumCulling.for_model(_toy(reflectance=0.3)) is None  # the floor mirrors the scene
    assert FrustumCulling.for_model(_toy(shadows=True)) is None  # the light's shadow map sees other geoms


def test_an_evaluation_rollout_sets_the_rasterizer_threads_unless_the_user_did(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    pytest.importorskip("torch")
    from abm.evaluation.runner import EvalJob, run_job
    from abm.evaluation.settings import EvalSettings

    missing = str(tmp_path / "no_model.pt")
    job = EvalJob(missing, "m", "place_food", "seen", 0, 0, 0, checkpoint=missing)
    monkeypatch.setenv(RASTERIZER_THREADS, "")  # recorded: the variable's own state comes back after the test
    monkeypatch.delenv(RASTERIZER_THREADS)
    assert run_job(job, EvalSettings()).error  # the policy cannot load: the setting came first
    assert os.environ[RASTERIZER_THREADS] == "0"
    monkeypatch.setenv(RASTERIZER_THREADS, "2")
    run_job(job, EvalSettings())
    assert os.environ[RASTERIZER_THREADS] == "2"


def test_the_rasterizer_runs_in_the_drawing_thread() -> None:
    """In a fresh process: set before the first GL context, llvmpipe starts no rasterizer threads."""
    script = textwrap.dedent("""
        import json, os
        from abm.sim.cameras import single_threaded_rasterizer
        single_threaded_rasterizer()
        from abm.sim.env import make_env
        from OpenGL import GL
        with make_env("pick_block", "seen", 1, resolution=32) as env:
            env.reset()
            renderer = GL.glGetString(GL.GL_RENDERER).decode()
            threads = [open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task")]
        print(json.dumps([renderer, threads]))
    """)
    env = {k: v for k, v in os.environ.items() if k != RASTERIZER_THREADS}
    env["PYTHONPATH"] = str(ROOT / "src")
    env.setdefault("MUJOCO_GL", "egl")
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    import json

    renderer, threads = json.loads(done.stdout.strip().splitlines()[-1])
    if "llvmpipe" not in renderer or not Path("/proc/self/task").is_dir():
        pytest.skip(f"the GL renderer is {renderer!r}, not Mesa's llvmpipe on Linux")
    assert not [t for t in threads if t.startswith("llvmpipe")], threads
