"""The ``contextweb`` command line: one entry point, one subcommand per job."""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path
from typing import Any

from core.experiments import EXPERIMENTS


def _add_experiment_parser(subparsers: Any) -> None:
    experiment = subparsers.add_parser("experiment", help="run one of the paper's experiments")
    names = experiment.add_subparsers(dest="experiment", required=True, metavar="NAME")
    for name, module_path in EXPERIMENTS.items():
        module = importlib.import_module(module_path)
        parser = names.add_parser(name, help=(module.__doc__ or "").strip().splitlines()[0] if module.__doc__ else None)
        parser.add_argument("--out", type=Path, default=Path("reports") / name, help="folder for the CSV and PNG files")
        parser.add_argument("--json", action="store_true", help="print the JSON summary on stdout")
        parser.add_argument("--quick", action="store_true", help="a small size, for tests")
        parser.add_argument("--seed", type=int, default=0, help="seed of every random choice")
        module.add_arguments(parser)
        parser.set_defaults(handler=_run_experiment, module=module)


def _run_experiment(args: argparse.Namespace) -> int:
    args.out.mkdir(parents=True, exist_ok=True)
    summary = args.module.run(args)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    if args.json:
        json.dump(summary, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(f"{args.experiment}: results in {args.out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="contextweb", description=__doc__)
    subparsers = parser.add_subparsers(dest="command", required=True)
    _add_experiment_parser(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.handler(args) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
