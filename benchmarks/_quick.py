"""What every benchmark's command line shares: ``--quick``, the same code path in seconds.

Not a benchmark (``tests/system/test_benchmarks_quick.py`` runs every script here but those
whose name starts with ``_``); the scripts import it as their sibling.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from typing import Any


def parse_args(
    parser: argparse.ArgumentParser,
    quick: Mapping[str, Any],
    argv: Sequence[str] | None = None,
) -> argparse.Namespace:
    """The options of ``argv`` (the command line when None); with ``--quick``, parsed again
    with ``quick`` as their defaults, so that an option given on the command line still wins."""
    args = parser.parse_args(argv)
    if args.quick:
        parser.set_defaults(**quick)
        args = parser.parse_args(argv)
    return args
