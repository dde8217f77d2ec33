"""``rtsid bench NAME [ARGS]``: run one benchmark and print its tables.

Only the chosen benchmark's module is imported (some pull in zenoh or spawn processes).
"""

from __future__ import annotations

import argparse
import importlib

from rtsid.benchmarks import BENCHMARKS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    listing = "; ".join(f"{name}: {text}" for name, (_, text) in BENCHMARKS.items())
    parser.add_argument("benchmark", choices=sorted(BENCHMARKS), metavar="NAME", help=listing)
    parser.add_argument("bench_args", nargs=argparse.REMAINDER, help="the benchmark's own options")


def benchmark_parser(name: str) -> tuple[argparse.ArgumentParser, object]:
    """Parser of one benchmark (with the shared ``--quick``) and its module."""
    module_name, help_text = BENCHMARKS[name]
    module = importlib.import_module(module_name)
    parser = argparse.ArgumentParser(prog=f"rtsid bench {name}", description=help_text)
    parser.add_argument("--quick", action="store_true", help="a short run to check it works")
    module.add_arguments(parser)
    return parser, module


def run(args: argparse.Namespace) -> int:
    parser, module = benchmark_parser(args.benchmark)
    bench_args = parser.parse_args(args.bench_args)
    return int(module.run(bench_args) or 0)  # type: ignore[attr-defined]
