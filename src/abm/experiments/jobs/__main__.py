"""``python -m abm.experiments.jobs JOB.json``: run one job the experiment engine wrote (:mod:`abm.experiments.jobs`)
in this process, as ``abm`` runs a command: abm's messages on stderr, a mistake the user can fix one
``abm: error: MESSAGE`` line (exit code 2, the line ``abm experiment status`` shows), Ctrl-C ``abm: interrupted``
(130), a bug its traceback (1); a training saves its step on SIGTERM (:mod:`abm.train.loop`)."""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from abm.errors import AbmError
from abm.experiments.jobs import read_job


def main(argv: Sequence[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m abm.experiments.jobs JOB.json", file=sys.stderr)
        return 2
    logger = logging.getLogger("abm")
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    logger.addHandler(handler)
    logger.propagate = False
    logger.setLevel(logging.INFO)
    try:
        read_job(Path(argv[0])).run()
    except AbmError as err:
        print(f"abm: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("abm: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
