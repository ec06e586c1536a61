"""``tractionecu inspect``: what a recording holds, and what was wrong with it."""

from __future__ import annotations

import argparse

from ..recording.reader import read_recording
from ..recording.summary import summarize


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="print duration, frame counts, rates, gaps and rejected lines of a recording")
    p.add_argument("recording", help="recording directory")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    rec = read_recording(args.recording)
    print(summarize(rec))
    return 0
