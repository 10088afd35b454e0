"""The project README's benchmark table is the one run_all renders from the committed JSON."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import run_all  # noqa: E402


def test_embed_replaces_only_the_marked_block():
    text = f"intro\n{run_all.START}\nold table\n{run_all.END}\nafter\n"
    out = run_all.embed(text, "| new |\n")
    assert out == f"intro\n{run_all.START}\n| new |\n{run_all.END}\nafter\n"
    assert run_all.embed("no markers here", "| x |\n") == "no markers here"


def test_readme_table_matches_the_committed_results():
    readme = (ROOT / "README.md").read_text()
    table = run_all.readme(run_all.load_results()).split("\n\n", 2)[2]
    assert run_all.embed(readme, table) == readme, \
        "README benchmark table is stale: run python benchmarks/run_all.py --readme"
