"""``abm view``: a local 3-D web viewer of an episode or of a policy rollout."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from abm.configuration import count, port_number, seed_int


def register(subparsers: argparse._SubParsersAction) -> None:
    from abm.configuration import clip_model_help

    p = subparsers.add_parser(
        "view", help="3-D browser viewer: point cloud, mask field, virtual views, heatmaps and keyframes",
        description="Serve a local web page (viser; works offline) showing, for each keyframe step, the fused "
        "point cloud coloured by RGB or by mask-field score, the target's points, the workspace cube, the five "
        "virtual cameras with their views (mask in cyan, the predicted translation heatmap on top), and the "
        "expert's (green) and predicted (orange) keyframes. Sources: --episode FILE (a demonstration; with --run "
        "also what the policy saw and predicted at each step), or --run RUN --task TASK (roll the policy out on "
        "the seeded scene abm eval uses).")
    p.add_argument("--episode", type=Path, help="episode file (.h5) to show")
    p.add_argument("--run", type=Path, help="training run folder or checkpoint: show its views and predictions")
    p.add_argument("--task", help="roll --run out on this ABM-Bench task instead of showing --episode")
    p.add_argument("--split", default="seen", choices=["seen", "unseen", "compositional"], help="rollout split")
    p.add_argument("--seed", type=seed_int, default=1_000_000,
                   help="rollout scene seed (abm eval's outcome log lists the seed of each episode)")
    p.add_argument("--steps", type=count, nargs="+", metavar="K", help="only these steps of --episode")
    p.add_argument("--grounder", choices=["oracle", "clip"], help="grounder (default: the checkpoint's, or oracle)")
    p.add_argument("--clip-model", help=clip_model_help("for --grounder clip", default=None))
    p.add_argument("--device", default="cpu", help="torch device of the policy")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default: localhost only)")
    p.add_argument("--port", type=port_number, default=8080, help="port (default: 8080)")
    p.add_argument("--screenshot", type=Path, metavar="PNG",
                   help="save a headless-Chromium screenshot of the page and exit instead of serving")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from abm.cli import CommandError

    log = logging.getLogger("abm")
    if (args.episode is None) == (args.task is None):
        raise CommandError("give --episode FILE (optionally with --run) or --run RUN --task TASK")
    if args.task is not None and args.run is None:
        raise CommandError("--task rolls a policy out: give its --run too")
    from abm.viewer.server import check_port

    check_port(args.host, args.port)  # a busy or bad address fails now, not after preparing the scene
    if args.screenshot is not None:
        from abm.viewer.browser import find_chromium

        if find_chromium() is None:
            raise CommandError("--screenshot needs Chromium, and none is on PATH: install it (Debian: apt-get "
                               "install chromium) or leave --screenshot out to serve the page")
    grounder = None
    if args.grounder:
        from abm.grounding.config import grounder_config_from_dict

        grounder = grounder_config_from_dict(
            {"kind": args.grounder, **({"model": args.clip_model} if args.clip_model else {})})
    policy = None
    if args.run is not None:
        from abm.policy import KeyframePolicy

        policy = KeyframePolicy.from_checkpoint(args.run, device=args.device, grounder=grounder)
    from abm.viewer.scene import rollout_scene, scene_from_episode

    start = time.perf_counter()
    if args.task is not None:
        log.info("rolling out %s on %s/%s seed %d ...", args.run, args.task, args.split, args.seed)
        scene = rollout_scene(policy, args.task, args.split, args.seed)
    else:
        if not args.episode.is_file():
            raise CommandError(f"--episode {args.episode} is not a file")
        from abm.data.episode_store import load_episode

        episode = load_episode(args.episode)
        scene = scene_from_episode(episode, policy=policy, grounder=grounder, steps=args.steps,
                                   progress=lambda done, total: log.info("step %d/%d ready", done, total))
    log.info("%d steps prepared in %.1f s", len(scene.steps), time.perf_counter() - start)

    from abm.viewer.server import serve

    viewer = serve(scene, args.host, args.port)
    try:
        if args.screenshot is not None:
            from abm.viewer.browser import screenshot

            screenshot(viewer.url, args.screenshot)
            log.info("screenshot written to %s", args.screenshot)
            return 0
        log.info("viewer at %s (Ctrl-C to stop)", viewer.url)
        while True:
            time.sleep(1.0)
    finally:
        viewer.close()
