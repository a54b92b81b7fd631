"""``abm view``: a local 3-D web viewer of an episode or of a policy rollout."""

from __future__ import annotations

import argparse
import logging
import time

from abm.data.episode_store import load_episode
from abm.errors import ConfigError, ExternalError
from abm.grounding.config import grounder_from_flags
from abm.policy import KeyframePolicy
from abm.viewer.browser import find_chromium, screenshot
from abm.viewer.record import record_from_episode, record_rollout
from abm.viewer.server import check_port, serve


def run(args: argparse.Namespace) -> int:
    log = logging.getLogger("abm")
    if (args.episode is None) == (args.task is None):
        raise ConfigError("give --episode FILE (optionally with --run) or --run RUN --task TASK")
    if args.task is not None and args.run is None:
        raise ConfigError("--task rolls a policy out: give its --run too")

    check_port(args.host, args.port)  # a busy or bad address fails now, not after preparing the record
    if args.screenshot is not None:
        if find_chromium() is None:
            raise ExternalError("--screenshot needs Chromium, and none is on PATH: install it (Debian: apt-get "
                                "install chromium) or leave --screenshot out to serve the page")
    grounder = grounder_from_flags(args.grounder, args.clip_model)
    policy = None
    if args.run is not None:
        policy = KeyframePolicy.from_checkpoint(args.run, device=args.device, grounder=grounder)

    start = time.perf_counter()
    if args.task is not None:
        log.info("rolling out %s on %s/%s seed %d ...", args.run, args.task, args.split, args.seed)
        record = record_rollout(policy, args.task, args.split, args.seed)
    else:
        if not args.episode.is_file():
            raise ConfigError(f"--episode {args.episode} is not a file")

        episode = load_episode(args.episode)
        record = record_from_episode(episode, policy=policy, grounder=grounder, steps=args.steps,
                                   progress=lambda done, total: log.info("step %d/%d ready", done, total))
    log.info("%d steps prepared in %.1f s", len(record.steps), time.perf_counter() - start)


    viewer = serve(record, args.host, args.port)
    try:
        if args.screenshot is not None:
            screenshot(viewer.url, args.screenshot)
            log.info("screenshot written to %s", args.screenshot)
            return 0
        log.info("viewer at %s (Ctrl-C to stop)", viewer.url)
        while True:
            time.sleep(1.0)
    finally:
        viewer.close()
