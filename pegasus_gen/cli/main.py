"""The `pegasus` command: one parser made of the command groups, and the error policy (one line, exit 2)."""

from __future__ import annotations

import argparse
import errno
import logging
import sys

from pegasus_gen import __version__
from pegasus_gen.cli import assets, dataset, demo, dope, render, robot, ros, scan
from pegasus_gen.errors import PegasusError

GROUPS = (render, dataset, assets, scan, dope, robot, ros, demo)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pegasus", description="Gaussian-splat scans to 6DoF pose datasets.")
    parser.add_argument("--version", action="version", version=f"pegasus {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log more")
    sub = parser.add_subparsers(dest="command", required=True)
    for group in GROUPS:
        group.add_commands(sub)
    return parser


# errors of the machine a command runs on, reported in one line: no space, over quota, read-only, no permission
ENVIRONMENT_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM}


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(message)s")
    try:
        return args.func(args)
    except PegasusError as exc:
        print(f"pegasus: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        if exc.errno not in ENVIRONMENT_ERRNOS:
            raise
        # the machine, not the program: a full disk, a read-only or unwritable place (files being written are
        # written beside their final name and renamed, so nothing half-written is left under it)
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"pegasus: error: {where}{exc.strerror}", file=sys.stderr)
        return 2
    except MemoryError:  # what the size checks before allocating did not foresee
        print("pegasus: error: out of memory (this machine, or its memory limit, gives the command less than it "
              "needs)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pegasus: interrupted", file=sys.stderr)
        return 130
