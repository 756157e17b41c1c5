"""JAX's persistent compilation cache for the command line: where it lives and switching it on.

Compiling the estimator takes seconds to tens of seconds per (image size, method); with the
cache a second process on the same machine loads the compiled executables from disk instead.
The folder also keeps the estimator's traced program (``exported/``, :mod:`jaxvo.runtime.aot`), since
JAX's cache is keyed by the lowered program and a cache hit would still trace it first.
``jaxvo run`` / ``jaxvo demo`` turn it on by default. Where it lives, first match wins:

1. ``--no-cache``: off;  ``--cache-dir DIR``: DIR;
2. the environment variable ``JAXVO_CACHE_DIR``: that folder; empty, ``0``, ``off``, ``false``
   or ``no`` turn the cache off;
3. ``$XDG_CACHE_HOME/jaxvo`` (``XDG_CACHE_HOME`` set and non-empty), else ``~/.cache/jaxvo``.

The library itself never switches the cache on (importing jaxvo changes no global JAX
setting); a program of your own calls :func:`enable` or sets JAX's own
``jax_compilation_cache_dir``.

Sharing the folder between processes is safe in the sense that it never gives a wrong result
or a crash: an entry's name is a hash of the compiled program, the JAX version, the backend
and the compile options, so different machines or jax versions never read each other's
entries; JAX writes an entry only if its file is absent, and an entry that cannot be read
(e.g. one that another process is still writing, or one truncated by a killed process) is
reported by JAX as a warning and compiled afresh. JAX's writes are not atomic (jax 0.10:
``pathlib.Path.write_bytes`` without a rename), so such a truncated entry stays until the
folder is deleted; deleting the folder is always safe. ``exported/`` is written atomically
(see :mod:`jaxvo.runtime.aot`). ``tests/test_cache.py`` starts two ``jaxvo run`` processes together on
an empty folder, then a third that must find every program there, traces no estimator and
gives bitwise the trajectory of a ``--no-cache`` run.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Optional

__all__ = ["ENV", "OFF_VALUES", "cache_dir", "enable"]

ENV = "JAXVO_CACHE_DIR"
OFF_VALUES = ("", "0", "off", "false", "no")


def cache_dir(option: Optional[os.PathLike] = None, disabled: bool = False,
              environ: Optional[Mapping[str, str]] = None) -> Optional[Path]:
    """The cache folder to use, or None when the cache is off (see the module docstring).

    Args:
      option: the ``--cache-dir`` value (None = not given).
      disabled: ``--no-cache``.
      environ: the environment (default ``os.environ``).
    """
    env = os.environ if environ is None else environ
    if disabled:
        return None
    if option is not None:
        return Path(option).expanduser()
    if ENV in env:
        v = env[ENV].strip()
        return None if v.lower() in OFF_VALUES else Path(v).expanduser()
    xdg = env.get("XDG_CACHE_HOME", "").strip()
    base = Path(xdg).expanduser() if xdg else Path(env.get("HOME", str(Path.home()))) / ".cache"
    return base / "jaxvo"


def enable(path: Optional[os.PathLike]) -> Optional[Path]:
    """Point JAX's persistent compilation cache at ``path`` (None: leave JAX's setting alone).

    Every compiled program is kept (minimum compile time 0 s, no minimum entry size), since
    even the estimator's small helpers take a noticeable fraction of a second each to compile
    on a small CPU. Call it before the first compilation of the process: JAX opens the cache
    folder once, at its first compilation.

    Returns the folder in use, or None when it cannot be created (then nothing is changed
    and the caller compiles without a cache).
    """
    if path is None:
        return None
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    if not os.access(path, os.W_OK | os.X_OK):
        return None
    import jax

    from jaxvo.runtime import aot

    aot.enable(path / "exported")  # the traced estimator too, so that a second process skips tracing
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    # -1: no minimum and no filesystem-dependent override by JAX
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    jax.config.update("jax_persistent_cache_enable_xla_caches", "none")
    return path
