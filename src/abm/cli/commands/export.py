"""``abm export`` (the parser: :mod:`abm.cli.train`; the export: :func:`abm.policy.export.export_model`)."""

from __future__ import annotations

import argparse

from abm.policy.export import export_model


def run(args: argparse.Namespace) -> int:
    export_model(args.run, args.out, args.dtype, args.overwrite)
    return 0
