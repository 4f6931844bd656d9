"""``python -m bench`` rewrites docs/benchmarks.md from the results: the hand-written header is kept,
the generated part is replaced by one table per result file."""

from __future__ import annotations

import json
from pathlib import Path

from bench.docs import MARKER, write_benchmarks_doc


def test_the_header_is_kept_and_the_tables_follow_the_results(tmp_path: Path) -> None:
    results = tmp_path / "results"
    results.mkdir()
    (results / "features.json").write_text(json.dumps({"mfcc": {"ms": 1.23456, "ratio": 3}, "runs": [1, 2]}))
    (results / "context.json").write_text(json.dumps({"series": list(range(50)), "note": "a|b"}))
    doc = tmp_path / "benchmarks.md"
    doc.write_text(
        f"# Benchmarks\n\nHand-written.\n\n{MARKER}\n\n## admission\n\n| `kept` | 9 |\n\n## features\n\n| `old` | 8 |\n"
    )

    write_benchmarks_doc(doc, results)
    text = doc.read_text()
    header, generated = text.split(MARKER)
    assert header == "# Benchmarks\n\nHand-written.\n\n"
    assert "| `old` | 8 |" not in generated, "a result file replaces its section"
    assert "## admission\n\n| `kept` | 9 |\n" in generated, "a benchmark without a result file here keeps its figures"
    assert generated.index("## admission") < generated.index("## context") < generated.index("## features")
    assert "| `mfcc.ms` | 1.235 |" in generated and "| `mfcc.ratio` | 3 |" in generated
    assert "| `runs` | 1, 2 |" in generated and "| `series` | (50 values) |" in generated
    assert "| `note` | a\\|b |" in generated

    write_benchmarks_doc(doc, results)
    assert doc.read_text() == text, "rewriting is idempotent"
