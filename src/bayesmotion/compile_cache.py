"""JAX's persistent compilation cache, for processes that start often (the command line, scripts).

Every new process compiles each program it runs. ``infer_emotion``'s first call on a model
compiles about 100 programs, and that, not the arithmetic, is most of a one-clip
``bayesmotion infer``. With the cache on, a compiled program is written to disk and a later
process with the same program reads it back instead of compiling it. A program is the same
when its code, shapes, JAX version and device are: a model's numbers are arguments, not part of
it, so a cache filled with one model serves another of the same structure and clip length.
What it saves is in ``benchmarks/results/compile_cache.json``; tracing and lowering still run in
each process, so a warm start is not free.

:func:`enable_compilation_cache` turns it on for this process (the command line does, unless
given ``--no-compile-cache``). The environment variable ``BAYESMOTION_COMPILE_CACHE`` names the
directory, or turns the cache off with ``off``; the default is a directory in the user's cache
folder (``platformdirs.user_cache_dir("bayesmotion")``), one subfolder per CPU (its
architecture and instruction-set flags), so a home folder shared between machines never hands
one CPU another's machine code. The folder is created private to the user (mode 0700): as JAX
warns, whoever can write to a compilation cache can make the processes that read it run code,
so never point it at a folder others can write. It is never pruned; deleting it is always safe.
"""

from __future__ import annotations

import hashlib
import os
import platform
from pathlib import Path

from bayesmotion.errors import BayesmotionError, warn

ENV = "BAYESMOTION_COMPILE_CACHE"
OFF = ("off", "0", "false", "no", "none")
_stats = {"enabled": None, "hits": 0, "misses": 0}


def _cpu_tag() -> str:
    """A short name for this CPU: its architecture and a hash of its instruction-set flags."""
    flags = ""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.split(":")[0].strip() in ("flags", "Features"):
                    flags = " ".join(sorted(line.split(":", 1)[1].split()))
                    break
    except OSError:
        flags = platform.processor()
    digest = hashlib.sha256(flags.encode()).hexdigest()[:12]
    return f"{platform.machine() or 'cpu'}-{digest}"


def default_directory() -> Path:
    """The cache directory used when neither an argument nor ``BAYESMOTION_COMPILE_CACHE``
    names one: ``<user cache folder>/bayesmotion/jax/<cpu tag>``."""
    import platformdirs

    return Path(platformdirs.user_cache_dir("bayesmotion")) / "jax" / _cpu_tag()


def _listen(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _stats["hits"] += 1
    elif event == "/jax/compilation_cache/cache_misses":
        _stats["misses"] += 1


def enable_compilation_cache(directory: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache for this process, every program cached
    however quickly it compiled.

    Args:
        directory: where the compiled programs go; default the environment variable
            ``BAYESMOTION_COMPILE_CACHE``, else :func:`default_directory`. An environment value
            of ``off`` (or ``0``, ``false``, ``no``, ``none``) turns the cache off, whatever
            ``directory`` says.

    Returns:
        The directory in use, or None when the cache is off or the directory cannot be created
        (a warning then says why and the process compiles as usual).

    Call it before the programs it should cache run: programs compiled earlier in the process
    are not written. Calling it again with another directory is refused with a warning (JAX
    reads its cache directory once per process), and the first stays in use.
    """
    import jax

    if directory is not None and not isinstance(directory, (str, os.PathLike)):
        raise BayesmotionError(f"enable_compilation_cache: directory must be a path, got "
                               f"{type(directory).__name__}")
    env = os.environ.get(ENV, "").strip()
    if env.lower() in OFF:
        return None
    path = Path(directory if directory is not None else env or default_directory()).expanduser()
    if _stats["enabled"] is not None:
        if path.resolve() != _stats["enabled"]:
            warn(f"the compilation cache is already on in {_stats['enabled']}; {path} is not "
                 f"used (JAX reads its cache directory once per process)")
        return _stats["enabled"]
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        if not os.access(path, os.W_OK | os.X_OK):
            raise PermissionError(f"cannot write to {path}")
    except OSError as e:
        warn(f"compilation cache off: {e}")
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.monitoring.register_event_listener(_listen)
    _stats["enabled"] = path.resolve()
    return _stats["enabled"]


def cache_stats() -> dict:
    """``{"directory": path or None, "hits": n, "misses": n}``: the cache in use and how many
    compilations it answered from disk (hits) or compiled and wrote (misses) since
    :func:`enable_compilation_cache` turned it on in this process."""
    d = _stats["enabled"]
    return {"directory": None if d is None else str(d), "hits": _stats["hits"],
            "misses": _stats["misses"]}
