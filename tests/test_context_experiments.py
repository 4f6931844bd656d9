"""The context experiments (Figs. 10, 11, Table VI) in their --quick sizes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from core.experiments import contexts, convergence, mixed


def _run(module: object, out: Path) -> dict:
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    args = parser.parse_args([])
    args.out, args.quick, args.seed, args.json = out, True, 0, False
    out.mkdir(parents=True, exist_ok=True)
    summary = module.run(args)
    json.dumps(summary)
    return summary


def test_contexts_experiment_records_fig11_and_where_growth_stops(tmp_path: Path) -> None:
    summary = _run(contexts, tmp_path)
    assert {p.name for p in tmp_path.iterdir()} == {"fig11.csv", "stop_k.csv", "fig11.png"}
    curve = summary["fig11"]["20"]["c_low"]["mean"]
    assert len(curve) == 3 and curve[0] > curve[2]
    assert summary["stop_k"]["paper@20"]["likelihood"] == [3, 3]
    assert summary["hit_rates"]["generic-2@30"]["likelihood"] == "2/2"


def test_convergence_experiment_traces_every_solver(tmp_path: Path) -> None:
    summary = _run(convergence, tmp_path)
    assert {p.name for p in tmp_path.iterdir()} == {"convergence.csv", "convergence.png"}
    assert set(summary["sweeps_to_converge"]) == set(convergence.SOLVERS)
    assert summary["entropy_after_first_sweep"]["k_incremental_scene"] < summary["entropy_after_first_sweep"]["batch"]
    finals = summary["final_entropy"].values()
    assert max(finals) - min(finals) < 0.25


def test_sweeps_to_converge_follows_its_definition() -> None:
    flat = [1.0] * 40
    traces = {"fast": [2.0, 1.5, *flat], "slow": [2.0] * 10 + flat, "stuck": [1.5] * 42}
    assert convergence.sweeps_to_converge(traces, tail=20) == {"fast": 2, "slow": 10, "stuck": None}


def test_mixed_experiment_predicts_table_vi(tmp_path: Path) -> None:
    summary = _run(mixed, tmp_path)
    assert {p.name for p in tmp_path.iterdir()} == {"table_vi.csv", "table_vi.png"}
    scenes = summary["scenes"]
    for name in ("kitchen", "playroom", "workshop"):
        assert scenes[name]["top_context_correct"], scenes[name]
        assert scenes[name]["ours"][name] > 0.9
    mixed_scene = scenes["playroom+workshop"]["ours"]
    assert mixed_scene["playroom"] > mixed_scene["workshop"] > mixed_scene["kitchen"]
    assert summary["mean_abs_error_vs_objects"]["ours"] < 0.1
