"""Command-line interface (filled in by the user-facing work; ``demo`` is the main job)."""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bayesmotion", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="the main job on the built-in emotional handshakes")
    demo.add_argument("--out", required=True)
    demo.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    if args.command == "demo":
        print("bayesmotion demo: not implemented yet", file=sys.stderr)
        return 2
    return 0
