"""The README's library quick start runs as written."""

import re
from pathlib import Path

import pytest

from bayesmotion.inference.posterior import ChainTooShortWarning

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.slow
@pytest.mark.optimized
def test_readme_quick_start_runs(capsys):
    text = README.read_text()
    block = re.search(r"## Library quick start\s+```python\n(.*?)```", text, re.S).group(1)
    assert len(block.strip().splitlines()) <= 16
    # the block's 60-step chain is deliberately short: the user must be told so
    with pytest.warns(ChainTooShortWarning, match="autocorrelation times"):
        exec(compile(block, "README quick start", "exec"), {})
    out = capsys.readouterr().out
    assert "True" in out.splitlines()[-1]  # the inferred label is the trial's label
