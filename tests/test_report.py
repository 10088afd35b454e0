"""The self-contained HTML report."""

import base64
import re
from pathlib import Path

import pytest

from bayesmotion.app.report import table, write_report
from bayesmotion.errors import BayesmotionError


def test_report_embeds_images_by_type_and_escapes_text(tmp_path):
    svg = tmp_path / "fig.svg"
    svg.write_text("<svg xmlns='http://www.w3.org/2000/svg'/>")
    gif = tmp_path / "a.gif"
    gif.write_bytes(b"GIF89a")
    out = tmp_path / "r.html"
    write_report(out, "A <b> & c", [("Sec <1>", [svg, gif, table([["<x>", 1]], ["h&"])])],
                 {"note": "<script>"})
    text = out.read_text()
    assert "<title>A &lt;b&gt; &amp; c</title>" in text and "<h2>Sec &lt;1&gt;</h2>" in text
    assert "<td>&lt;x&gt;</td>" in text and "<th>h&amp;</th>" in text
    assert "<script>" not in text
    mimes = re.findall(r'src="data:([^;]+);base64,([^"]+)"', text)
    assert [m for m, _ in mimes] == ["image/svg+xml", "image/gif"]
    assert base64.b64decode(mimes[1][1]) == b"GIF89a"
    bad = tmp_path / "x.bmp"
    bad.write_bytes(b"BM")
    with pytest.raises(BayesmotionError, match="x.bmp"):
        write_report(tmp_path / "r2.html", "t", [("s", [Path(bad)])], {})
    assert not (tmp_path / "r2.html").exists()
