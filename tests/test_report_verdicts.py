"""The report's verdicts (experiments.report.claims), computed from hand-made summaries."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from experiments.report import Status, Verdict
from experiments.report.claims import (
    fig_9,
    fig_10,
    fig_11,
    fig_12,
    fig_13,
    fig_14,
    fig_15,
    fig_16,
    running_times,
    table_vi,
)


def _sigma(best: float) -> dict[str, Any]:
    sigmas = [round(0.1 * i, 1) for i in range(11)]
    curve = [-abs(s - best) - 0.2 for s in sigmas]
    return {"sigmas": sigmas, "log_likelihood": curve, "best_sigma": best, "overall_accuracy": [0.6] * 10 + [0.95]}


def test_fig_9_reproduced_inside_the_papers_interval_else_names_the_measured_sigma() -> None:
    assert fig_9.judge(_sigma(0.4)).status is Status.REPRODUCED
    assert fig_9.judge(_sigma(0.5)).status is Status.REPRODUCED
    verdict = fig_9.judge(_sigma(0.8))
    assert verdict.status is Status.NOT_REPRODUCED
    assert "σ = 0.8" in verdict.reason and "concept web" in verdict.reason and "95%" in verdict.reason
    assert "the context" in fig_9.judge(_sigma(0.2)).reason


def _mixed(kitchen_share: float) -> dict[str, Any]:
    """Table VI's 50/50 scene, the Kitchen predicted at ``kitchen_share`` (paper: 0.4667 / 0.5156 / 0.0177)."""
    ours = {"kitchen": kitchen_share, "workshop": 1.0 - kitchen_share, "playroom": 0.0}
    return {
        "scenes": {
            "kitchen+workshop": {
                "true": {"kitchen": 0.5, "workshop": 0.5},
                "true_by_tokens": {"kitchen": 0.37, "workshop": 0.63},
                "paper": {"kitchen": 0.4667, "workshop": 0.5156, "playroom": 0.0177},
                "ours": ours,
                "ours_std": dict.fromkeys(ours, 0.01),
            }
        }
    }


def test_table_vi_checks_every_proportion_against_the_truth_within_the_papers_own_worst_error() -> None:
    assert table_vi.TABLE_VI_TOLERANCE == 0.071  # playroom+workshop's Workshop: 26.23 % for 1/3
    assert table_vi.judge(_mixed(0.44)).status is Status.REPRODUCED  # within 0.071, error above the paper's
    assert table_vi.judge(_mixed(0.49)).status is Status.BETTER  # also below the paper's mean |error|
    verdict = table_vi.judge(_mixed(0.42))  # 0.08 off: within the old 0.15, not the paper's 0.071
    assert verdict.status is Status.NOT_REPRODUCED
    assert "2 of 3 proportions off by more than 0.071" in verdict.reason
    assert "kitchen+workshop / workshop: 0.58" in verdict.reason and "0.63 by tokens" in verdict.reason


def _recognition(
    accuracy: tuple[float, float, float, float],
    true_noun: tuple[float, float, float, float] = (0.5, 0.6, 0.7, 0.8),
    corrected: tuple[int, int] = (2, 0),
) -> dict[str, Any]:
    """Perception, web, Eq. 6 and the log pool: overall accuracies and mean P(true noun); Eq. 6's
    (corrected, broken) nouns (the log pool's are the same)."""
    methods = ("perception", "concept_web", "in_context", "in_context_log")
    summary: dict[str, Any] = {
        method: {"noun_accuracy": value, "adjective_accuracy": value, "overall_accuracy": value}
        for method, value in zip(methods, accuracy, strict=True)
    }
    summary["noun_confidence"] = {
        method: {"mean_true_noun": value, "share_top_below_half": 0.5, "median_top": 0.6}
        for method, value in zip(methods, true_noun, strict=True)
    }
    changes = {"corrected": corrected[0], "broken": corrected[1]}
    summary["noun_changes"] = {"concept_web": changes, "in_context": changes, "in_context_log": changes}
    return summary


def test_fig_13_needs_strict_gains_nouns_corrected_and_the_true_nouns_confidence_rising() -> None:
    assert fig_13.judge(_recognition((0.8, 0.85, 0.9, 0.9))).status is Status.REPRODUCED
    tie = fig_13.judge(_recognition((0.8, 0.8, 0.9, 0.9)))
    assert tie.status is Status.NOT_REPRODUCED and "web accuracy 0.800 ≯ perception 0.800" in tie.reason
    assert fig_13.judge(_recognition((0.8, 0.85, 0.9, 0.9), corrected=(1, 1))).status is Status.NOT_REPRODUCED
    lowered = fig_13.judge(_recognition((0.8, 0.85, 0.9, 0.9), true_noun=(0.5, 0.6, 0.55, 0.7)))
    assert lowered.status is Status.NOT_REPRODUCED
    assert "P(true noun) Eq. 6 0.550 ≯ web 0.600" in lowered.reason and "the log pool would pass" in lowered.reason
    both = fig_13.judge(_recognition((0.8, 0.9, 0.85, 0.85)))
    assert "Eq. 6 accuracy 0.850 ≯ web 0.900" in both.reason and "the log pool would not pass either" in both.reason


def _noise(in_context_at_half: list[float]) -> dict[str, Any]:
    return {
        "noise_levels": [0.1, 0.5, 0.9],
        "sigmas": [0.1, 0.5, 0.9],
        "perception_accuracy": [0.9, 0.5, 0.2],
        "in_context_accuracy": [[0.0, value, 0.0] for value in in_context_at_half],
    }


def test_fig_14_compares_at_the_papers_sigma_at_every_noise_level_and_keeps_a_majority_right() -> None:
    assert fig_14.judge(_noise([0.9, 0.6, 0.55])).status is Status.REPRODUCED
    verdict = fig_14.judge(_noise([0.9, 0.6, 0.1]))
    assert verdict.status is Status.NOT_REPRODUCED
    assert "noise 90% (0.100 vs 0.200)" in verdict.reason and "10%" not in verdict.reason
    floor = fig_14.judge(_noise([0.9, 0.6, 0.3]))  # above the prototypes everywhere, below 0.5 at 90 %
    assert floor.status is Status.NOT_REPRODUCED and "not above the floor 0.5 at noise 90% (0.300)" in floor.reason


def _planning(kitchen: float, playroom: float, workshop: float, counts: tuple[int, int, int]) -> dict[str, Any]:
    reductions = {"kitchen": kitchen, "playroom": playroom, "workshop": workshop}
    return {
        "scenarios": 100,
        "fig_15_paper_counts": dict(zip(fig_15.PAPER_FIG_15_NODES, counts, strict=True)),
        "median_nodes": {
            "paper": {c: {"unpruned": 100.0, "pruned": 100.0 * (1 - r), "reduction": r} for c, r in reductions.items()}
        },
    }


def test_figs_15_and_16_canonical_counts_and_pruning_order() -> None:
    paper = _planning(0.8, 0.5, 0.0, (2380, 156, 820))
    assert fig_15.judge(paper).status is Status.REPRODUCED
    assert fig_16.judge(paper).status is Status.REPRODUCED
    assert fig_15.judge(_planning(0.8, 0.5, 0.0, (2380, 157, 820))).status is Status.NOT_REPRODUCED
    assert fig_16.judge(_planning(0.5, 0.8, 0.0, (2380, 156, 820))).status is Status.NOT_REPRODUCED
    assert fig_16.judge(_planning(0.8, 0.5, 0.1, (2380, 156, 820))).status is Status.NOT_REPRODUCED


def _raw_vs_web(web: int | None, raw: int | None, worst: float, fine: int | None = None) -> dict[str, Any]:
    return {
        "scenes_to_exceed_half": {"concept_web": web, "raw_10_bins": raw, "raw_50_bins": fine},
        "score_by_scenes": {"raw_50_bins": [0.3, 0.96 if fine else 0.4]},
        "grid_worst": {"concept_web": worst},
    }


def test_fig_12_web_above_half_by_five_scenes_before_raw_and_robust_on_the_grid() -> None:
    assert fig_12.judge(_raw_vs_web(5, 50, 0.6)).status is Status.REPRODUCED
    assert fig_12.judge(_raw_vs_web(1, 50, 0.6)).status is Status.BETTER
    assert fig_12.judge(_raw_vs_web(10, 50, 0.6)).status is Status.NOT_REPRODUCED
    assert fig_12.judge(_raw_vs_web(5, 5, 0.6)).status is Status.NOT_REPRODUCED
    assert fig_12.judge(_raw_vs_web(3, None, 0.45)).status is Status.NOT_REPRODUCED
    assert fig_12.judge(_raw_vs_web(None, None, 0.6)).status is Status.NOT_REPRODUCED
    fine = fig_12.judge(_raw_vs_web(5, 50, 0.6, fine=50))  # 50 bins must fail, as the paper says
    assert fine.status is Status.NOT_REPRODUCED
    assert "raw 50 bins exceeds 0.5 from 50 scenes (score 0.96)" in fine.reason


def _contexts(found_at_20: list[int], k_of_min_entropy: int = 3, c_low_at_3: float = 0.0) -> dict[str, Any]:
    """10 test sets at |D| = 1 (ignored: below the paper's 3 scenes) and at |D| = 20 (all contexts present)."""
    curve = {
        "c_low": {"mean": [6.0, 3.0, c_low_at_3], "std": [1.0, 1.0, 0.0]},
        "entropy": {"mean": [0.9, 0.8, 0.7], "std": [0.0] * 3},
        "k_of_min_entropy": k_of_min_entropy,
    }
    return {
        "fig11": {"1": {**curve, "k_of_min_entropy": 1}, "20": curve},
        "stop_k": {
            "paper@1": {"present": [1] * 10, "scenes": [2] * 10, "likelihood": [2] * 10, "paper": [2] * 10},
            "paper@20": {"present": [3] * 10, "scenes": found_at_20, "likelihood": [2] * 10, "paper": [6] * 10},
        },
    }


def test_fig_11_growth_must_stop_at_the_contexts_present_in_nine_of_ten_test_sets() -> None:
    assert fig_11.judge_stop(_contexts([3] * 9 + [4])).status is Status.REPRODUCED
    verdict = fig_11.judge_stop(_contexts([3] * 8 + [2, 4]))
    assert verdict.status is Status.NOT_REPRODUCED
    assert "8/10 test sets at |D| = 20" in verdict.reason and "|D| = 20: 0/10" in verdict.reason
    assert "|D| = 1" not in verdict.reason


def test_fig_11_growth_must_also_stop_at_three_where_every_context_is_present() -> None:
    summary = _contexts([3] * 10)
    summary["stop_k"]["paper-all@20"] = {"present": [3] * 10, "scenes": [3] * 8 + [2, 2], "paper": [6] * 10}
    verdict = fig_11.judge_stop(summary)
    assert verdict.status is Status.NOT_REPRODUCED
    assert "8/10 test sets at |D| = 20 (every context present)" in verdict.reason
    summary["stop_k"]["paper-all@20"]["scenes"] = [3] * 9 + [2]
    assert fig_11.judge_stop(summary).status is Status.REPRODUCED


def test_fig_11_curves_need_no_uncertain_concept_and_least_entropy_at_three() -> None:
    assert fig_11.judge_curves(_contexts([3] * 10)).status is Status.REPRODUCED
    verdict = fig_11.judge_curves(_contexts([3] * 10, k_of_min_entropy=2, c_low_at_3=1.5))
    assert verdict.status is Status.NOT_REPRODUCED
    assert verdict.reason == (
        "mean |C_low| at K = 3: 1.5 (|D| = 20); minimum H̃ at K = 2 (|D| = 20: 0.800 vs 0.700 nats at K = 3)"
    )
    only_entropy = fig_11.judge_curves(_contexts([3] * 10, k_of_min_entropy=2))
    assert only_entropy.reason.startswith("minimum H̃ at K = 2")


def _convergence(incremental: float | None, batch: float | None, final_gap: float) -> dict[str, Any]:
    medians = {"k_incremental_c_low": incremental, "k_incremental_scene": 12.0, "batch": batch}
    return {
        "summary": {
            "smoothed": {
                solver: {"converged": "10/10" if median is not None else "0/10", "median": median, "quartiles": None}
                for solver, median in medians.items()
            }
        },
        "final_entropy": {"k_incremental_c_low": 0.78 + final_gap, "k_incremental_scene": 0.78, "batch": 0.78},
    }


def test_fig_10_incremental_converges_faster_to_the_same_entropy() -> None:
    assert fig_10.judge(_convergence(10.0, 20.0, 0.01)).status is Status.REPRODUCED
    assert fig_10.judge(_convergence(10.0, None, 0.01)).status is Status.REPRODUCED
    assert fig_10.judge(_convergence(30.0, 20.0, 0.01)).status is Status.NOT_REPRODUCED
    assert fig_10.judge(_convergence(10.0, 20.0, 0.2)).status is Status.NOT_REPRODUCED
    stuck = fig_10.judge(_convergence(None, 20.0, 0.2))
    assert stuck.status is Status.NOT_REPRODUCED
    assert "k incremental c low: converged in 0/10 runs, median — sweeps" in stuck.reason
    assert "k incremental scene: converged in 10/10 runs, median 12 sweeps" in stuck.reason


@pytest.mark.parametrize(
    ("detection_ms", "web_ms", "status"),
    [(0.1, 0.2, Status.BETTER), (210.0, 1390.0, Status.REPRODUCED), (300.0, 0.2, Status.NOT_REPRODUCED)],
)
def test_running_times_against_the_papers_mean_and_spread(detection_ms: float, web_ms: float, status: Status) -> None:
    summary = {"context_detection_ms": detection_ms, "web_convergence_ms": web_ms, "source": "test"}
    assert running_times.judge(summary).status is status


def test_running_times_come_from_the_benchmarks_when_present(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    measured = {"context_detection_ms": 1.0, "web_convergence_ms": 2.0, "source": "measured"}
    monkeypatch.setattr(running_times, "measure_running_times", lambda seed: measured)
    assert running_times.running_times(tmp_path, seed=0) is measured
    (tmp_path / "context.json").write_text(json.dumps({"detection_5_objects": {"ours_median_us": 70.0}}))
    (tmp_path / "concept_web.json").write_text(json.dumps({"ours_median_us": 200.0}))
    times = running_times.running_times(tmp_path, seed=0)
    assert times["context_detection_ms"] == pytest.approx(0.07) and times["web_convergence_ms"] == pytest.approx(0.2)


def test_verdict_lines() -> None:
    assert Verdict(Status.NOT_REPRODUCED, "σ = 0.8").line() == "not reproduced — σ = 0.8"
    assert Verdict(Status.NOT_RUN, "ValueError: x").line() == "not run: ValueError: x"
