"""JAX's persistent compilation cache: where it lives, switching it on, and keeping it sound.

Compiling the estimator takes seconds to tens of seconds per (image size, method); with the
cache a later process on the same machine loads the compiled executables from disk instead.
The folder also keeps jaxvo's traced programs, the estimator's and the tracking's (``exported/``,
:mod:`jaxvo.runtime.aot`), since JAX's cache is keyed by the lowered program and a cache hit would
still trace it first.

**On by default.** ``import jaxvo`` switches it on (:func:`use_default`), for the library and
every command; where it lives, first match wins:

1. the commands' ``--no-cache``: off;  ``--cache-dir DIR``: DIR;  the library's :func:`enable` /
   :func:`disable` (``jaxvo.runtime.cache``), called at any time;
2. the environment variable ``JAXVO_CACHE_DIR``: that folder; empty, ``0``, ``off``, ``false``
   or ``no`` turn the cache off;
3. ``$XDG_CACHE_HOME/jaxvo`` (``XDG_CACHE_HOME`` set and non-empty), else ``~/.cache/jaxvo``.

A program that set JAX's own ``jax_compilation_cache_dir`` before importing jaxvo keeps it:
then jaxvo switches nothing on by default. Otherwise JAX's cache setting is process-wide, so a
program's own jitted functions are kept in the folder too.

**Sound.** An entry's name is a hash of the compiled program, the JAX version, the backend and
the compile options, so different machines or jax versions never read each other's entries;
nothing in it depends on where the folder is (JAX's GPU autotuning cache, whose folder path
would enter every key, is left off), so a copied or moved folder still hits. Entries are
written under a temporary name and renamed, and an entry that cannot be read (truncated or
empty: a full disk, a killed writer) is removed and compiled again, with one note line
(:mod:`jaxvo.runtime.notes`) instead of JAX's warnings. Deleting the folder is always safe.
Loading an entry runs its program, so the folder must be as trusted as the user's own files.

``tests/test_cache.py`` starts two ``jaxvo run`` processes together on an empty folder, then a
third that must find every program there, traces no estimator and gives bitwise the trajectory
of a ``--no-cache`` run; and a second library process that reaches its first estimate without
compiling, from a copied folder.
"""
from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import Mapping, Optional

from jaxvo.runtime.notes import note_once

__all__ = ["ENV", "OFF_VALUES", "cache_dir", "enable", "disable", "folder", "use_default", "is_cold", "stats"]

ENV = "JAXVO_CACHE_DIR"
OFF_VALUES = ("", "0", "off", "false", "no")

# the folder in use (None: off) and whether enable/disable/use_default has decided it
_STATE = {"folder": None, "decided": False, "listening": False}
_STATS = {"requests": 0, "hits": 0, "repaired": 0}


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
    """Keep JAX's compiled programs and jaxvo's exported ones in ``path`` from now on (None:
    leave the setting as it is). Any earlier folder of this process is left.

    Every compiled program is kept (minimum compile time 0 s, no minimum entry size), since
    even the estimator's small helpers take a noticeable fraction of a second each to compile
    on a small CPU.

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

    aot.enable(path / "exported")  # the traced programs too, so that a second process skips tracing
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    # -1: no minimum and no filesystem-dependent override by JAX
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    # JAX's default puts the GPU autotuning cache's folder, an absolute path, into the compile
    # options and so into every entry's key: a copied or moved folder would never hit
    jax.config.update("jax_persistent_cache_enable_xla_caches", "none")
    _install_checked_cache()
    _listen()
    _STATE.update(folder=path, decided=True)
    return path


def disable() -> None:
    """Switch the cache off for the rest of this process (JAX's and the exported programs)."""
    import jax

    from jaxvo.runtime import aot

    aot.enable(None)
    jax.config.update("jax_compilation_cache_dir", None)
    _reset_jax_cache()
    _STATE.update(folder=None, decided=True)


def folder() -> Optional[Path]:
    """The cache folder in use in this process (None: off)."""
    return _STATE["folder"]


def use_default() -> Optional[Path]:
    """Switch the cache on at :func:`cache_dir`'s folder unless this process already decided
    (:func:`enable`, :func:`disable`), ``JAXVO_CACHE_DIR`` turns it off, or the program set
    JAX's own cache folder. ``import jaxvo`` calls it. Returns the folder in use (None: off);
    a folder that cannot be created gives one note line and no cache."""
    if _STATE["decided"]:
        return _STATE["folder"]
    _STATE["decided"] = True
    import jax

    if jax.config.jax_compilation_cache_dir:
        return None
    want = cache_dir()
    if want is None:
        return None
    if enable(want) is None:
        note_once("cache-folder", f"{want}: cannot create the compilation cache folder; every process compiles "
                                  f"again (set {ENV} to another folder, or {ENV}=off)")
    return _STATE["folder"]


def is_cold(path: Optional[os.PathLike] = None) -> bool:
    """Whether the next estimate will compile from scratch: the folder (``path``, default the one
    in use) holds no program exported by this jaxvo and jax for this device, or the cache is
    off. True on a machine's first run and after an update of jaxvo or jax; a command can say
    then that the first frames wait for the compilation (seconds to a minute). Starts JAX's
    backend (it asks for the device)."""
    from jaxvo.runtime import aot

    p = Path(path) if path is not None else _STATE["folder"]
    if p is None:
        return True
    return not aot.has_programs(p / "exported")


def stats() -> dict:
    """Counts in this process: compilations that looked in the persistent cache
    (``requests``), those that found their program there (``hits``), and broken entries
    removed (``repaired``). ``requests - hits`` programs were compiled."""
    return dict(_STATS)


def _listen() -> None:
    """Count JAX's cache events (:func:`stats`), once per process."""
    if _STATE["listening"]:
        return
    from jax import monitoring

    def on_event(event: str, **kwargs) -> None:
        if event == "/jax/compilation_cache/compile_requests_use_cache":
            _STATS["requests"] += 1
        elif event == "/jax/compilation_cache/cache_hits":
            _STATS["hits"] += 1

    monitoring.register_event_listener(on_event)
    _STATE["listening"] = True


def _reset_jax_cache() -> None:
    """Make JAX open its cache folder afresh at the next compilation (it opens it once)."""
    try:
        from jax._src import compilation_cache as cc

        cc.reset_cache()
    except Exception:  # noqa: BLE001 - another jax: JAX keeps the folder it opened first
        pass


def _install_checked_cache() -> None:
    """Put :class:`_CheckedCache` in the place of JAX's file cache. Where this jax's internals
    differ, JAX's own cache stays (it then warns about a broken entry and keeps it)."""
    try:
        from jax._src import compilation_cache as cc

        cc.reset_cache()
        with cc._cache_initialized_mutex:
            cc._cache = _CheckedCache()
            cc._cache_initialized = True
    except Exception:  # noqa: BLE001
        _reset_jax_cache()


class _CheckedCache:
    """JAX's file cache of the folder that ``jax_compilation_cache_dir`` names (followed if a
    program changes it), with reads checked and writes atomic.

    get: an entry that does not decompress (truncated or empty) is removed and reported as
    absent, so JAX compiles the program again and writes it anew. put: written to a temporary
    name and renamed, so other processes never read a part; a failed write (a full disk)
    leaves no file and gives one note line."""

    def __init__(self):
        self._base = None
        self._dir = None

    def _cache(self):
        """JAX's file cache of the configured folder (None: no folder)."""
        import jax
        from jax._src import compilation_cache as cc

        d = jax.config.jax_compilation_cache_dir
        if d != self._dir:
            self._base = cc.get_file_cache(d)[0] if d else None
            self._dir = d
        return self._base

    @property
    def _path(self):   # what JAX's reset_cache logs
        return self._dir

    def _file(self, key: str) -> Path:
        """Where JAX's file cache keeps the entry ``key`` (call after :meth:`_cache`)."""
        from jax._src import lru_cache

        return Path(self._dir) / f"{key}{getattr(lru_cache, '_CACHE_SUFFIX', '-cache')}"

    def get(self, key: str):
        from jax._src import compilation_cache as cc

        base = self._cache()
        blob = None if base is None else base.get(key)
        if blob is None:
            return None
        try:
            if len(cc.decompress_executable(blob)) > 4:   # 4 bytes of compile time, then the program
                return blob
        except Exception:  # noqa: BLE001 - whatever the decompressor raises for a broken stream
            pass
        path = self._file(key)
        try:
            path.unlink()
        except OSError:
            pass
        _STATS["repaired"] += 1
        note_once("cache-repaired", f"{path.parent}: removed a broken compilation-cache entry (truncated or empty: "
                                    f"a full disk or a killed process); compiling it again")
        return None

    def put(self, key: str, value: bytes) -> None:
        base = self._cache()
        if base is None:
            return
        if getattr(base, "eviction_enabled", True):   # a size limit: JAX's own locking writer
            base.put(key, value)
            return
        path = self._file(key)
        if path.exists():
            return
        tmp = path.parent / f".{path.name}.{os.getpid()}.{uuid.uuid4().hex}.tmp"
        try:
            tmp.write_bytes(value)
            os.replace(tmp, path)
        except OSError as e:
            try:
                tmp.unlink()
            except OSError:
                pass
            note_once("cache-write", f"{path.parent}: cannot write the compilation cache ({e.strerror or e}); "
                                     f"this process goes on without keeping what it compiles")

    def clear(self) -> None:
        base = self._cache()
        if base is not None:
            base.clear()
