"""The documentation's results page holds the tables run_all renders from the committed JSON."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import run_all  # noqa: E402

RESULTS_PAGE = ROOT / "docs" / "results.md"


def test_embed_replaces_only_the_marked_block():
    text = f"intro\n{run_all.START}\nold table\n{run_all.END}\nafter\n"
    out = run_all.embed(text, "| new |\n")
    assert out == f"intro\n{run_all.START}\n| new |\n{run_all.END}\nafter\n"
    assert run_all.embed("no markers here", "| x |\n") == "no markers here"
    study = f"a\n{run_all.STUDY_START}\nold\n{run_all.STUDY_END}\nb\n"
    assert run_all.embed(study, "| s |\n") == study  # other markers: untouched
    assert run_all.embed(study, "| s |\n", run_all.STUDY_START, run_all.STUDY_END) == \
        f"a\n{run_all.STUDY_START}\n| s |\n{run_all.STUDY_END}\nb\n"


def test_results_page_matches_the_committed_results():
    page = RESULTS_PAGE.read_text()
    for marker in (run_all.START, run_all.END, run_all.STUDY_START, run_all.STUDY_END):
        assert marker in page, f"docs/results.md lacks the marker {marker}"
    assert run_all.render_docs(page, run_all.load_results()) == page, \
        "docs/results.md is stale: run python benchmarks/run_all.py --docs"


def test_the_readme_holds_no_benchmark_table():
    readme = (ROOT / "README.md").read_text()
    assert run_all.START not in readme and run_all.END not in readme


def test_docs_flag_and_its_readme_alias(monkeypatch):
    calls = []
    monkeypatch.setattr(run_all, "write_readme", lambda: calls.append(1))
    assert run_all.main(["--docs"]) == 0 and run_all.main(["--readme"]) == 0
    assert calls == [1, 1]


def test_the_header_names_every_jax_version_and_its_results():
    m = lambda v: {"machine": {"jax": v}}  # noqa: E731
    assert run_all.jax_versions({"a": m("0.9.2"), "b": m("0.9.2")}) == "jax 0.9.2"
    assert run_all.jax_versions({"a": m("0.9.2"), "b": m("0.10.2"), "c": m("0.9.2")}) == \
        "jax 0.9.2 (jax 0.10.2: b)"
    assert run_all.jax_versions({"a": {}}) == "jax ?"
