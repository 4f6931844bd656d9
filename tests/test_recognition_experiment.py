"""The recognition experiment (§V-D, Table VII, Fig. 13) end to end, in --quick size."""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from experiments import recognition

#: Not one of the report's seeds (0-4): a test must not pin what the report judges.
TEST_SEED = 7

EXTRA = "perception_copy"


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """One --quick run, with a third method registered the way the context work adds "in_context"."""
    out = tmp_path_factory.mktemp("recognition")
    parser = argparse.ArgumentParser()
    recognition.add_arguments(parser)
    args = parser.parse_args([])
    args.out, args.json, args.quick, args.seed = out, False, True, TEST_SEED
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(recognition.METHODS, EXTRA, recognition.perception_only)
        summary = recognition.run(args)
    return out, summary


def test_summary_reports_every_method_and_the_prototype_comparison(quick_run: tuple[Path, dict[str, Any]]) -> None:
    _, summary = quick_run
    json.dumps(summary)  # JSON-serialisable, as the CLI writes it
    assert summary["n_test_objects"] == 6  # one per noun in --quick
    for method in (*recognition.METHODS, EXTRA):
        for key in ("noun_accuracy", "adjective_accuracy", "overall_accuracy"):
            assert 0.0 <= summary[method][key] <= 1.0
    assert summary[EXTRA] == summary["perception"]
    assert summary["perception"]["noun_accuracy"] >= 0.5  # chance is 1/6
    comparison = summary["prototype_comparison"]
    assert 0.5 < comparison["label_agreement"] <= 1.0 and 0.0 <= comparison["irrelevant_jaccard"] <= 1.0
    assert set(summary["temperatures"]) == {"noun", "adjective", "verb"}
    assert summary["paper"]["figure"].startswith("Fig. 13")


def test_csv_has_one_row_per_object_and_method(quick_run: tuple[Path, dict[str, Any]]) -> None:
    out, summary = quick_run
    with (out / "results.csv").open(encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    methods = {*recognition.METHODS, EXTRA}
    assert {"perception", "concept_web"} <= methods
    assert len(rows) == len(methods) * summary["n_test_objects"]
    assert {row["method"] for row in rows} == methods
    for row in rows:
        assert float(row["noun_accuracy"]) == float(row["predicted_noun"] == row["noun"])
        overall = (float(row["noun_accuracy"]) + 5 * float(row["adjective_accuracy"])) / 6
        assert float(row["overall_accuracy"]) == pytest.approx(overall)
    web = [float(row["adjective_accuracy"]) for row in rows if row["method"] == "concept_web"]
    assert np.mean(web) == pytest.approx(summary["concept_web"]["adjective_accuracy"])


def test_figure_and_tables_are_written(quick_run: tuple[Path, dict[str, Any]]) -> None:
    out, summary = quick_run
    assert (out / "recognition.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = (out / "table_vii.txt").read_text(encoding="utf-8")
    assert [line.split(":")[0] for line in table.splitlines() if not line.startswith(" ")] == summary["examples"]
    assert len(summary["examples"]) == recognition.EXAMPLES
    assert table.count("nouns:") == (len(recognition.METHODS) + 1) * recognition.EXAMPLES
    prototypes = (out / "prototypes.txt").read_text(encoding="utf-8").splitlines()
    assert len(prototypes) == 1 + 29  # legend + the paper's 29 concepts
