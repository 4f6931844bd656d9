"""The ``contextweb`` command line: one entry point, one subcommand per job.

Only the chosen command's parser is built, so ``contextweb serve`` does not
import the experiments (matplotlib, every numba module) it never runs.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Callable
from pathlib import Path

from pydantic import ValidationError

from storage.migrations import SchemaNotAtHead


def _build_experiment(parser: argparse.ArgumentParser) -> None:
    from experiments import EXPERIMENTS

    names = parser.add_subparsers(dest="experiment", required=True, metavar="NAME")
    for name, module_path in EXPERIMENTS.items():
        module = importlib.import_module(module_path)
        experiment = names.add_parser(name, help=(module.__doc__ or name).strip().splitlines()[0])
        experiment.add_argument(
            "--out", type=Path, default=Path("reports") / name, help="folder for the CSV and PNG files"
        )
        experiment.add_argument("--json", action="store_true", help="print the JSON summary on stdout")
        experiment.add_argument("--quick", action="store_true", help="a small size, for tests")
        experiment.add_argument("--seed", type=int, default=0, help="seed of every random choice")
        module.add_arguments(experiment)
        experiment.set_defaults(handler=_run_experiment, module=module)


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


def _build_serve(parser: argparse.ArgumentParser) -> None:
    from app import serve

    serve.add_serve_arguments(parser)
    parser.set_defaults(handler=serve.run_serve)


def _build_migrate(parser: argparse.ArgumentParser) -> None:
    from app import serve

    parser.set_defaults(handler=serve.run_migrate)


def _build_bridge(parser: argparse.ArgumentParser) -> None:
    tools = parser.add_subparsers(dest="tool", required=True, metavar="TOOL")
    for name, module_name in (("simulate", "sim.robot"), ("replay", "bridge.tools.replay")):
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as missing:  # simulate needs the `experiments` extra (tqdm); replay does not
            tool = tools.add_parser(name, help=f"unavailable: {missing}", add_help=False)
            tool.add_argument("arguments", nargs=argparse.REMAINDER)
            tool.set_defaults(handler=_missing_extra(f"bridge {name}", missing))
            continue
        tool = tools.add_parser(name, help=(module.__doc__ or name).strip().splitlines()[0])
        module.add_arguments(tool)
        tool.set_defaults(handler=module.run)


def _missing_extra(command: str, missing: ModuleNotFoundError) -> Callable[[argparse.Namespace], int]:
    """A handler that says which optional dependency a command needs, instead of a traceback."""

    def handler(_: argparse.Namespace) -> int:
        print(
            f"contextweb {command}: {missing.name} is not installed; "
            "install it with: pip install 'contextweb[experiments]'",
            file=sys.stderr,
        )
        return 69

    return handler


def _build_models(parser: argparse.ArgumentParser) -> None:
    from app import models_cli

    models_cli.add_arguments(parser)


def _build_keys(parser: argparse.ArgumentParser) -> None:
    from app import keys_cli

    keys_cli.add_arguments(parser)


def _build_report(parser: argparse.ArgumentParser) -> None:
    from experiments import report

    report.add_arguments(parser)
    parser.set_defaults(handler=report.run)


def _build_prototypes(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    show = actions.add_parser(
        "show", help="fit the prototypes on the paper world's training objects and print Table VIII"
    )
    show.add_argument("--seed", type=int, default=0, help="seed of the world, its recordings and the clustering")
    show.add_argument(
        "--method", choices=["rgng", "kmeans"], default="rgng", help="clustering in the mean-variance plane"
    )
    show.set_defaults(handler=_show_prototypes)


def _show_prototypes(args: argparse.Namespace) -> int:
    from core.prototypes import fit_prototypes, format_prototype_table
    from experiments.context_scenes import object_features
    from experiments.recognition import training_data
    from sim.world import World

    world = World.paper(seed=args.seed)
    features = object_features(world, world.train_objects, args.seed)
    prototypes = fit_prototypes(
        world.vocabulary, *training_data(world.train_objects, features), method=args.method, seed=args.seed
    )
    print(format_prototype_table(prototypes))
    return 0


#: sysexits' EX_CONFIG: the CONTEXTWEB_* settings are invalid.
EXIT_BAD_SETTINGS = 78
#: sysexits' EX_TEMPFAIL: the database is not at the head revision; ``contextweb migrate``, then
#: the same command again, succeeds (a server started before its deployment's migration finished).
EXIT_SCHEMA_NOT_AT_HEAD = 75

#: Command -> (help, builder of its parser). A builder imports what its command needs.
COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None]]] = {
    "serve": ("run the web service (after `contextweb migrate`)", _build_serve),
    "migrate": ("bring the database to the latest schema", _build_migrate),
    "experiment": ("run one of the paper's experiments", _build_experiment),
    "report": ("run every experiment and write the reproduction report", _build_report),
    "prototypes": ("the concept prototypes of Table VIII", _build_prototypes),
    "bridge": ("feed a running service: simulate the iCub world, replay recordings", _build_bridge),
    "models": ("check the stored models against the storage invariants, repair their counts", _build_models),
    "keys": ("create, list and revoke the API keys of robots and dashboards", _build_keys),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser with every command listed and ``command``'s own options built."""
    parser = argparse.ArgumentParser(prog="contextweb", description=__doc__.splitlines()[0])
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (help_text, build) in COMMANDS.items():
        subparser = subparsers.add_parser(name, help=help_text, description=help_text)
        if name == command:
            build(subparser)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    command = next((word for word in argv if not word.startswith("-")), None)
    args = build_parser(command).parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except ValidationError as error:  # the CONTEXTWEB_* settings: one line each, not a traceback
        if error.title != "Settings":
            raise
        for problem in error.errors():
            field = ".".join(str(part) for part in problem["loc"])
            where = f"CONTEXTWEB_{field.upper()}: " if field else ""
            print(f"contextweb {args.command}: {where}{problem['msg']}", file=sys.stderr)
        return EXIT_BAD_SETTINGS
    except SchemaNotAtHead as error:  # one line, as for the settings: the fix is one command
        print(f"contextweb {args.command}: {error}", file=sys.stderr)
        return EXIT_SCHEMA_NOT_AT_HEAD


if __name__ == "__main__":
    raise SystemExit(main())
