"""``rtsid bench NAME``: run one benchmark and print its tables."""

from __future__ import annotations

import argparse
import importlib

from rtsid.benchmarks import BENCHMARKS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="benchmark", metavar="NAME", required=True)
    for name, (module_name, help_text) in BENCHMARKS.items():
        cmd = sub.add_parser(name, help=help_text, description=help_text)
        cmd.set_defaults(_bench=module_name)
        cmd.add_argument("--quick", action="store_true", help="a short run to check it works")
        # Arguments of the benchmark itself are added lazily (its module may import heavy parts).
        importlib.import_module(module_name).add_arguments(cmd)


def run(args: argparse.Namespace) -> int:
    return int(importlib.import_module(args._bench).run(args) or 0)
