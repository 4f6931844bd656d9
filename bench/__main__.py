"""Run every ``bench/bench_*.py`` module's ``main()`` in turn: ``python -m bench [NAME ...] [--option ...]``.

With names (e.g. ``features``), only the ``bench_<name>`` modules run. Options
(arguments starting with ``-``, e.g. ``--quick``) are passed on to every benchmark,
which sees them in ``sys.argv`` as if it had been run with ``python -m bench.bench_<name>``.
Afterwards ``docs/benchmarks.md`` is rewritten from every ``bench/results/*.json`` (bench/docs.py);
``--docs-only`` rewrites it without running anything.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys

import bench
from bench.docs import write_benchmarks_doc


def bench_modules(names: list[str]) -> list[str]:
    """Module paths of the benchmarks to run, sorted; all of them when ``names`` is empty."""
    found = sorted(info.name for info in pkgutil.iter_modules(bench.__path__) if info.name.startswith("bench_"))
    wanted = {f"bench_{name.removeprefix('bench_')}" for name in names}
    unknown = wanted - set(found)
    if unknown:
        raise SystemExit(f"unknown benchmark(s): {', '.join(sorted(unknown))}; known: {', '.join(found)}")
    return [f"bench.{name}" for name in found if not wanted or name in wanted]


def main(argv: list[str]) -> int:
    names = [arg for arg in argv if not arg.startswith("-")]
    options = [arg for arg in argv if arg.startswith("-") and arg != "--docs-only"]
    if "--docs-only" not in argv:
        for module_path in bench_modules(names):
            print(f"== {module_path}", flush=True)
            sys.argv = [module_path, *options]
            importlib.import_module(module_path).main()
    print(f"== {write_benchmarks_doc()} rewritten from {bench.RESULTS}/*.json", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
