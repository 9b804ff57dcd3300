"""``-v/--verbose`` for the commands that drive an arm: the deploy loop's per-episode lines
(started, outcome) and its warnings, or warnings only."""

from __future__ import annotations

import argparse
import logging


def add_verbose(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "-v", "--verbose", action="store_true", help="log each episode's start and outcome"
    )


def configure_logging(args: argparse.Namespace) -> None:
    level = logging.INFO if args.verbose else logging.WARNING
    logging.basicConfig(level=level, format="%(levelname)s %(message)s")
