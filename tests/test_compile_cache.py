"""JAX's persistent compilation cache (bayesmotion.compile_cache): a second process reads the
programs the first compiled, the folder is private, the command line turns it on and off."""

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from bayesmotion import compile_cache
from bayesmotion.app import cli
from bayesmotion.errors import BayesmotionError

# a jitted function, enabled cache, a second enable elsewhere; prints the result and the stats
PROGRAM = r"""
import json, sys, warnings
import jax, jax.numpy as jnp
import bayesmotion
from bayesmotion.compile_cache import cache_stats, enable_compilation_cache
d = enable_compilation_cache()
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    again = enable_compilation_cache(sys.argv[1])
f = jax.jit(lambda x: jnp.sin(x) @ jnp.cos(x).T + jnp.linalg.cholesky(x @ x.T + 3 * jnp.eye(3)))
y = f(jnp.arange(9.0).reshape(3, 3) / 9)
print(json.dumps({"dir": str(d), "again": str(again), "warned": [str(m.message) for m in w],
                  "y": y.tolist(), **cache_stats()}))
"""


def _run(env_value: str, other: Path) -> dict:
    env = {**os.environ, compile_cache.ENV: env_value}
    out = subprocess.run([sys.executable, "-c", PROGRAM, str(other)], env=env,
                         capture_output=True, text=True, timeout=300, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_second_process_reads_what_the_first_compiled(tmp_path):
    cache = tmp_path / "cache"
    first = _run(str(cache), tmp_path / "elsewhere")
    assert Path(first["dir"]) == cache.resolve()
    assert first["misses"] >= 1 and first["hits"] == 0
    assert any(cache.iterdir())
    assert stat.S_IMODE(cache.stat().st_mode) == 0o700
    # JAX reads its cache folder once: a second folder is refused with a warning
    assert first["again"] == first["dir"]
    assert first["warned"] and "already on" in first["warned"][0]
    assert not (tmp_path / "elsewhere").exists()

    second = _run(str(cache), tmp_path / "elsewhere")
    assert second["hits"] >= 1 and second["misses"] == 0
    assert second["y"] == first["y"]


@pytest.mark.parametrize("value", ["off", "0", "OFF", "none"])
def test_the_environment_turns_it_off(value, monkeypatch, tmp_path):
    monkeypatch.setenv(compile_cache.ENV, value)
    assert compile_cache.enable_compilation_cache(tmp_path / "c") is None
    assert not (tmp_path / "c").exists()
    assert compile_cache.cache_stats()["directory"] is None


def test_a_folder_that_cannot_be_made_warns_and_leaves_it_off(monkeypatch, tmp_path):
    monkeypatch.delenv(compile_cache.ENV)
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.warns(UserWarning, match="compilation cache off"):
        assert compile_cache.enable_compilation_cache(blocker / "cache") is None
    assert compile_cache.cache_stats()["directory"] is None


def test_a_directory_that_is_not_a_path_is_refused():
    with pytest.raises(BayesmotionError, match="directory must be a path, got int"):
        compile_cache.enable_compilation_cache(5)


def test_default_folder_is_per_cpu_in_the_user_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    d = compile_cache.default_directory()
    assert d.parent == tmp_path / "bayesmotion" / "jax"
    arch, digest = d.name.rsplit("-", 1)
    assert arch and len(digest) == 12
    assert compile_cache.default_directory() == d  # stable within a machine


@pytest.mark.parametrize("flag, calls", [([], 1), (["--no-compile-cache"], 0)])
def test_the_command_line_turns_it_on_unless_told_not_to(flag, calls, monkeypatch, tmp_path,
                                                         capsys):
    seen = []
    monkeypatch.setattr(cli, "enable_compilation_cache", lambda: seen.append(1))
    # a command that stops at its input check: the cache is turned on before the command runs
    code = cli.main(flag + ["view", str(tmp_path / "missing.bvh"), "--out",
                            str(tmp_path / "v.html")])
    assert code == 2 and "missing.bvh" in capsys.readouterr().err
    assert len(seen) == calls


def test_infer_many_workers_turn_on_the_callers_cache(monkeypatch):
    from bayesmotion.emotion import batch

    seen = []
    monkeypatch.setattr(batch, "enable_compilation_cache", seen.append)
    monkeypatch.setattr(batch, "worker_model", lambda data: data)
    monkeypatch.setattr(batch, "infer_row", lambda model, name, paths, kw: {"clip": name})
    assert batch._task(b"model", "c", ("a.bvh",), {}, "/cache/dir") == {"clip": "c"}
    assert batch._task(b"model", "d", ("b.bvh",), {}) == {"clip": "d"}
    assert seen == ["/cache/dir"]  # a task without a folder leaves the worker's setting alone
