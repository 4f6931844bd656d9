"""The context experiments (Figs. 10, 11, Table VI) in their --quick sizes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from core.context import IncrementalLDA, LDAState
from core.context import _gibbs_kernels as kernels
from core.errors import InvalidInputError
from experiments import contexts, convergence, mixed
from sim.world import WorldConfig, generate_scenes

#: Not one of the report's seeds (0-4): a test must not pin what the report judges.
TEST_SEED = 7


def _run(module: object, out: Path, argv: tuple[str, ...] = ()) -> dict:
    parser = argparse.ArgumentParser()
    module.add_arguments(parser)
    args = parser.parse_args(argv)
    args.out, args.quick, args.seed, args.json = out, True, TEST_SEED, False
    out.mkdir(parents=True, exist_ok=True)
    summary = module.run(args)
    json.dumps(summary)
    return summary


def test_contexts_experiment_records_fig11_and_where_growth_stops(tmp_path: Path) -> None:
    # The mechanics on label documents; growth on perceived webs: test_context_scene_partition.py.
    summary = _run(contexts, tmp_path, ("--documents", "labels"))
    assert {p.name for p in tmp_path.iterdir()} == {"fig11.csv", "stop_k.csv", "fig11.png"}
    curve = summary["fig11"]["20"]["c_low"]["mean"]
    assert len(curve) == 3 and curve[0] > curve[2]
    assert summary["stop_k"]["paper@20"]["scenes"] == [3, 3]
    assert summary["stop_k"]["paper@3"]["scenes"] == summary["stop_k"]["paper@3"]["present"]
    assert summary["hit_rates"]["generic-2@30"]["scenes"] == "2/2"
    assert set(summary["hit_rates"]["paper@20"]) == {"scenes", "likelihood", "paper"}
    assert summary["stop_k"]["paper-all@3"]["present"] == [3, 3]


def test_convergence_experiment_traces_every_solver(tmp_path: Path) -> None:
    # The paper's 100 scenes (Fig. 10), two test sets, short runs.
    summary = _run(convergence, tmp_path, ("--scenes", "100", "--sweeps", "80", "--tail", "20"))
    assert {p.name for p in tmp_path.iterdir()} == {"convergence.csv", "convergence.png"}
    names = {*convergence.SOLVERS, convergence.CONTROL}
    assert set(summary["sweeps_to_converge"]) == set(summary["sweeps_to_converge_unsmoothed"]) == names
    converged = summary["sweeps_to_converge"]
    # The scene split charges its 3 scans as 3 sweeps and is done about then; batch needs more.
    for split, batch in zip(converged["k_incremental_scene_split"], converged["batch"], strict=True):
        assert split is not None and 3 <= split and (batch is None or split <= batch)
    # Its low H̃ is the true split: after the scans the scenes sit in their true contexts.
    found = summary["true_contexts_found_at_sweep"]
    assert found["k_incremental_scene_split"][3] == "2/2" and found["batch"][3] == "0/2"
    # The already stationary control calibrates the smoothed rule: converged from its first sweep.
    assert converged[convergence.CONTROL] == [0, 0]
    at_10 = {name: at[10] for name, at in summary["mean_entropy_at_sweep"].items()}
    assert at_10["k_incremental_scene_split"] < at_10["k_incremental_scene"] < at_10["batch"]
    finals = [summary["final_entropy"][name] for name in ("k_incremental_scene", "k_incremental_scene_split", "batch")]
    assert max(finals) - min(finals) < 0.05


def test_sweeps_to_converge_follows_its_definition() -> None:
    flat = [1.0] * 40
    traces = {"fast": [2.0, 1.5, *flat], "slow": [2.0] * 10 + flat, "stuck": [1.5] * 42}
    assert convergence.sweeps_to_converge(traces, tail=20) == {"fast": 2, "slow": 10, "stuck": None}
    # One noisy sweep resets the unsmoothed count but not the mean over 10 sweeps; a control
    # is scored against the solvers' target without moving it (as a solver, its lower level
    # would leave "flat" unconverged).
    noisy = {"noisy": [2.0] * 5 + [1.0] * 10 + [1.05] + [1.0] * 24, "flat": [1.0] * 40}
    control = {"control": [0.5] * 40}
    assert convergence.sweeps_to_converge(noisy, tail=10, controls=control) == {"noisy": 16, "flat": 0, "control": 0}
    assert convergence.sweeps_to_converge(noisy, tail=10, window=10, controls=control) == {
        "noisy": 5,
        "flat": 0,
        "control": 0,
    }


def test_split_start_moves_whole_scenes_with_their_exact_probability() -> None:
    # Six scenes, K = 2 plus the new context 2; scene 2's first token is anchored in the new context.
    rng = np.random.default_rng(0)
    offsets = np.concatenate([[0], np.cumsum(rng.integers(3, 9, size=6))]).astype(np.int32)
    words = rng.integers(0, 5, size=offsets[-1]).astype(np.int32)
    start = LDAState.from_arrays(0.3, 0.2, 5, 2, words, rng.integers(0, 2, size=offsets[-1]).astype(np.int32), offsets)
    previous = start.n_dk.argmax(axis=1)
    anchored = np.zeros(offsets[-1], dtype=bool)
    anchored[offsets[2]] = True
    start.grow_k_incrementally(anchored, 0.0, np.random.default_rng(1))
    scene = np.arange(offsets[2], offsets[3])
    block = scene[~anchored[scene] & np.isin(start.assignments[scene], [previous[2], 2])]

    def joint_with_block_in(context: int) -> float:
        state = LDAState.from_arrays(0.3, 0.2, 5, 3, words, start.assignments.copy(), offsets)
        state.reassign(block, np.full(block.shape[0], context, dtype=np.int32))
        return state.joint_log_likelihood()

    p_move = 1.0 / (1.0 + np.exp(joint_with_block_in(previous[2]) - joint_with_block_in(2)))
    for u, expected in ((p_move - 1e-9, 2), (p_move + 1e-9, previous[2])):
        state = LDAState.from_arrays(0.3, 0.2, 5, 3, words, start.assignments.copy(), offsets)
        kernels.split_scenes(
            state._words, state._z, state.doc_offsets, np.array([2]), previous, anchored,
            state._n_wk, state._n_k, state._n_dk, 2, 0.3, 0.2, 5, np.array([u]),
        )  # fmt: skip
        assert np.all(state.assignments[block] == expected)
        others = np.setdiff1d(np.arange(offsets[-1]), block)
        assert np.array_equal(state.assignments[others], start.assignments[others])
        assert state.invariant_violations() == []


def test_split_start_keeps_the_anchor_moves_whole_scenes_and_is_seeded() -> None:
    scenes = [scene.tokens() for scene in generate_scenes(WorldConfig.paper(), 60, 3)]
    saved = IncrementalLDA(seed=3, sweeps=50).fit(scenes, n_contexts=2).to_state()

    def grown(split_scans: int) -> LDAState:
        state = IncrementalLDA.from_state(saved).lda_state
        worst = int(np.argmin(state.scene_fit()))
        anchor = np.zeros(state.n_tokens, dtype=bool)
        anchor[state.doc_offsets[worst] : state.doc_offsets[worst + 1]] = True
        state.grow_k_incrementally(anchor, 0.05, np.random.default_rng(7), split_scans=split_scans)
        assert np.all(state.assignments[anchor] == 2) and state.invariant_violations() == []
        return state

    def scenes_in_new_context(state: LDAState) -> int:
        return int((state.n_dk[:, 2] >= 0.9 * state.doc_lengths).sum())

    plain, split = grown(0), grown(3)
    assert scenes_in_new_context(plain) == 1  # the anchor's scene; δ moves single tokens
    assert scenes_in_new_context(split) > 10
    assert np.array_equal(grown(3).assignments, split.assignments)
    with pytest.raises(InvalidInputError, match="^split_scans"):
        plain.grow_k_incrementally(np.zeros(plain.n_tokens, dtype=bool), 0.05, np.random.default_rng(7), split_scans=-1)


def test_mixed_experiment_predicts_table_vi(tmp_path: Path) -> None:
    # On label documents: --quick's perceived documents come from prototypes fitted on 3 objects per
    # noun. Table VI's accuracy is the report's to judge (full size, five seeds, the paper's 0.071):
    # at --quick size (20 training scenes, 2 repeats) seed 7 gives the pure Playroom only 0.50
    # (Workshop 0.40) and the 2/3 Playroom scene 0.29 — the > 0.9 this test asserted held at seed 0.
    summary = _run(mixed, tmp_path, ("--documents", "labels"))
    assert {p.name for p in tmp_path.iterdir()} == {"table_vi.csv", "table_vi.png"}
    assert summary["documents"] == "labels" and summary["contexts_found"] == [3, 3]
    scenes = summary["scenes"]
    for name in ("kitchen", "playroom", "workshop"):
        assert scenes[name]["top_context_correct"], scenes[name]
        assert sum(scenes[name]["ours"].values()) == pytest.approx(1.0, abs=1e-3)
