"""jaxvo's programs (the estimator's, the tracking's) kept on disk, traced and compiled, so that a
later process neither traces nor lowers them.

JAX's persistent compilation cache (:mod:`jaxvo.runtime.cache`) is keyed by the *lowered* program:
a process that finds its compiled estimator there must still trace and lower it first
(about 3 s at 640x480 on a small CPU, most of a second process's start-up; the tracking's
programs about as much again). This module keeps, in the folder given to :func:`enable`
(``jaxvo.runtime.cache.enable`` uses ``<cache folder>/exported``), each program twice:

* its traced program, a ``jax.export`` serialization (``.jaxexport``): a later process
  deserializes it and compiles its call without tracing (a hit in JAX's cache);
* on the CPU, the executable XLA compiled from it (``.xla``, ``jax.experimental.serialize_executable``),
  named also by the processor it was compiled for (:func:`jaxvo.runtime.machine.instruction_set`):
  a later process on such a processor loads it and calls it as it is, without lowering it or
  asking JAX's cache (at 640x480 about a fifth of a second less before the first pose). Only an
  executable XLA compiled in this process is written (:func:`_compile`).

The first process traces once, exports, compiles, writes both files and runs the compiled
program (one trace, one XLA compilation, as without this module).

A file is named ``<function>-<environment>-<program>.jaxexport``: a hash of the environment
(:func:`environment_tag`, so that :func:`has_programs` tells whether a folder holds anything
for this jaxvo, jax and device) and a hash of everything that determines the program: the function's name,
the jax and jaxlib versions, the backend (platform, its version, device kind), JAX's
configuration values (but those of logging, caches and dumps) and ``XLA_FLAGS``, the source of every module of the jaxvo package,
and the arguments' pytree structure (which holds the static fields of ``Config`` and the
image size of ``Camera``) and abstract values (shape, dtype, weak type); its executable
``<function>-<environment>-<program>-<processor>.xla``. A file whose checksum, format or
abstract signature does not match is ignored and rewritten (a bad executable: the exported
program is compiled instead); any error while exporting, reading or running a program falls
back to the ordinary jit path, so the worst a bad file costs is the time of tracing. Files are written under a
temporary name and renamed (``os.replace``), so processes sharing the folder read either
no file or a complete one; two processes that export the same program write equivalent
files (they differ only in the source locations kept for error messages). Deleting the folder is always safe. Loading a file runs its program, so the folder
must be as trusted as JAX's own cache folder (the user's cache directory).

Exporting a program means compiling it (seconds to a minute): the first export of a process
gives one note line (:mod:`jaxvo.runtime.notes`) saying so.

``jax.export`` serialization needs the ``flatbuffers`` package; without it every call takes
the jit path. Calls whose arguments are tracers (``jax.vmap`` / ``jax.jit`` of the
estimator) always take the jit path.

:class:`Program` bundles a function with its name, jit and compiler options for :func:`call`,
and makes it ready ahead of its first call (:meth:`Program.compile_ahead`, e.g. in a thread
while the estimator is traced): its executable read in a process that finds it, traced,
written and compiled in one that does not. An exported program's
outputs are committed to the device (:func:`sharding`); :func:`placed` puts the state that such
outputs replace there from the start, so that the plain jits that read it compile once.
"""
from __future__ import annotations

import hashlib
import os
import re
import threading
import uuid
from pathlib import Path
from typing import Callable, Dict, Optional, Tuple

import jax
import numpy as np

from jaxvo.runtime import lapack
from jaxvo.runtime.notes import note_once

__all__ = ["Program", "call", "compile_ahead", "enable", "environment_tag", "folder", "has_programs", "placed",
           "program_key", "sharding", "stats"]

_MAGIC = b"jaxvo-exported-1\n"
_EXECUTABLE_MAGIC = b"jaxvo-executable-1\n"
_FOLDER: Dict[str, Optional[Path]] = {"path": None}
# per (name, tree, argument signature) in this process: the compiled program, or None = use jit
_PROGRAMS: Dict[tuple, Optional[Callable]] = {}
# one lock per memo key: a program made ready in a thread (compile_ahead) is read or traced once,
# and a call that needs it meanwhile waits for it
_LOCKS: Dict[tuple, threading.Lock] = {}
_LOCKS_LOCK = threading.Lock()
_STATS = {"executables": 0, "loaded": 0, "exported": 0, "fallbacks": 0}
_SOURCE: Dict[str, str] = {}
# per thread: whether its latest compilation read JAX's cache (set by :func:`_on_event`)
_COMPILED = threading.local()
_LISTENING = {"on": False}
# JAX settings that never change a traced program (logging, caches, dumps), left out of the
# file name so that e.g. JAX_LOG_COMPILES=1 still finds the program
_UNRELATED = re.compile(r"log|cache|explain|dump|traceback|pprint|transfer_guard|profil|timeout|verbose|report")


def enable(path: Optional[os.PathLike]) -> Optional[Path]:
    """Keep exported programs in ``path`` (created if missing); None switches it off.
    Returns the folder in use, or None when it cannot be created. The programs this process
    has made ready stay ready while the folder stays the same (a command that switches on the
    folder already in use reloads nothing); another folder, or none, starts afresh."""
    p = None if path is None else Path(path)
    if p is not None:
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError:
            p = None
    if p != _FOLDER["path"]:
        _PROGRAMS.clear()
    _FOLDER["path"] = p
    return p


def folder() -> Optional[Path]:
    """The folder of exported programs in use (None: off)."""
    return _FOLDER["path"]


def stats() -> dict:
    """Counts in this process: compiled ``executables`` read from files, exported programs
    ``loaded`` from files (then compiled: a hit in JAX's cache), ``exported`` (traced and written),
    and ``fallbacks`` to the jit path; for tests and benchmarks."""
    return dict(_STATS)


def _source_hash() -> str:
    if "hash" not in _SOURCE:
        h = hashlib.sha256()
        root = Path(__file__).resolve().parents[1]   # the whole package: any change of the code is a new program
        for f in sorted(root.rglob("*.py")):
            h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes() + b"\0")
        _SOURCE["hash"] = h.hexdigest()
    return _SOURCE["hash"]


def _environment() -> str:
    import jaxlib

    dev = jax.devices()[0]
    settings = sorted((k, repr(v)) for k, v in jax.config.values.items()
                      if (v is None or isinstance(v, (bool, int, float, str))) and not _UNRELATED.search(k))
    return repr((jax.__version__, jaxlib.__version__, dev.platform, dev.device_kind, dev.client.platform_version,
                 os.environ.get("XLA_FLAGS", ""), settings, _source_hash()))


def environment_tag() -> str:
    """16 hex digits naming this environment (jax, jaxlib, device, JAX settings, XLA_FLAGS,
    jaxvo's source): part of every exported program's file name."""
    return hashlib.sha256(_environment().encode()).hexdigest()[:16]


def has_programs(path: os.PathLike) -> bool:
    """Whether the folder ``path`` holds a program exported in this environment (:func:`environment_tag`)."""
    try:
        return any(Path(path).glob(f"*-{environment_tag()}-*.jaxexport"))
    except OSError:
        return False


def _avals(leaves) -> tuple:
    return tuple(str(jax.typeof(x)) for x in leaves)


def _signature(leaves) -> tuple:
    """What fixes the abstract values of ``leaves``, cheaply (every call looks it up)."""
    # a NumPy array and a JAX array of the same shape and dtype are the same input to the program
    # (so are a NumPy scalar and a jax.ShapeDtypeStruct, compile_ahead's stand-in for them)
    return tuple(("array", x.shape, x.dtype, getattr(x, "weak_type", False))
                 if isinstance(x, (np.ndarray, np.generic, jax.Array, jax.ShapeDtypeStruct))
                 else (type(x), getattr(x, "shape", None), getattr(x, "dtype", None), getattr(x, "weak_type", None))
                 for x in leaves)


def program_key(name: str, args) -> str:
    """The hex name of ``name``'s exported program for these arguments (see the module docstring)."""
    leaves, tree = jax.tree.flatten(args)
    return hashlib.sha256(repr((name, str(tree), _avals(leaves), _environment())).encode()).hexdigest()


def _read(path: Path, leaves):
    """The Exported stored at ``path`` if it is complete and fits ``leaves``, else None."""
    from jax import export

    try:
        blob = path.read_bytes()
    except OSError:
        return None
    head = len(_MAGIC) + 32
    if len(blob) < head or not blob.startswith(_MAGIC) or hashlib.sha256(blob[head:]).digest() != blob[len(_MAGIC):head]:
        return None
    exp = export.deserialize(bytearray(blob[head:]))
    # (an exported signature drops weak types; the file name holds them)
    if [(a.shape, a.dtype) for a in exp.in_avals] != [(t.shape, t.dtype) for t in map(jax.typeof, leaves)]:
        return None
    return exp


def _write(path: Path, payload: bytes, magic: bytes = _MAGIC) -> None:
    """Write atomically: a temporary file in the same folder, then ``os.replace``."""
    tmp = path.parent / f"{path.name}.{os.getpid()}.{uuid.uuid4().hex}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)  # the umask applies, as for JAX's files
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(magic + hashlib.sha256(payload).digest() + payload)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def _executable_path(path: Path) -> Path:
    """Where the compiled executable of the exported program ``path`` is kept: beside it, named
    also by this machine's processor (:func:`jaxvo.runtime.machine.instruction_set`), for which
    XLA generated its code."""
    from jaxvo.runtime.machine import instruction_set

    isa = hashlib.sha256(instruction_set().encode()).hexdigest()[:8]
    return path.with_name(f"{path.name[:-len('.jaxexport')]}-{isa}.xla")


def _trees(n_in: int, n_out: int):
    """The argument and result trees of an exported program's call: ``run(*leaves)`` -> a tuple."""
    return jax.tree.structure((tuple(range(n_in)), {})), jax.tree.structure(tuple(range(n_out)))


def _lapack_ready() -> None:
    """Point XLA's CPU LAPACK kernels (Cholesky and triangular solves of the solvers) at their
    implementations (:func:`jaxvo.runtime.lapack.ready`). JAX does so while it lowers a program
    that calls them; an executable read from a file is never lowered, and running it before
    would call a null kernel."""
    if jax.devices()[0].platform == "cpu":
        lapack.ready()


def _read_executable(path: Path, leaves):
    """The compiled program stored at ``path``, loaded onto the device, if the file is complete
    and its arguments are ``leaves``' shapes and dtypes; else None."""
    from jax.experimental import serialize_executable

    try:
        blob = path.read_bytes()
    except OSError:
        return None
    head = len(_EXECUTABLE_MAGIC) + 32
    if len(blob) < head + 4 or not blob.startswith(_EXECUTABLE_MAGIC) \
            or hashlib.sha256(blob[head:]).digest() != blob[len(_EXECUTABLE_MAGIC):head]:
        return None
    n_out = int.from_bytes(blob[head:head + 4], "little")
    _lapack_ready()
    compiled = serialize_executable.deserialize_and_load(blob[head + 4:], *_trees(len(leaves), n_out))
    args = jax.tree.leaves(compiled.args_info, is_leaf=lambda a: hasattr(a, "donated"))   # jax.stages.ArgInfo
    if [(a.shape, a.dtype) for a in args] != [(t.shape, t.dtype) for t in map(jax.typeof, leaves)]:
        return None
    return compiled


def _on_event(event: str, **kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":   # recorded in the thread that compiles
        _COMPILED.from_cache = True


def _compile(jitted, leaves):
    """``jitted.lower(*leaves).compile()`` and whether XLA compiled it here (not read from JAX's cache)."""
    if not _LISTENING["on"]:
        from jax import monitoring

        monitoring.register_event_listener(_on_event)
        _LISTENING["on"] = True
    _COMPILED.from_cache = False
    compiled = jitted.lower(*leaves).compile()
    return compiled, not _COMPILED.from_cache


def _write_executable(path: Path, compiled, n_in: int) -> None:
    """Keep ``compiled`` (a ``jax.stages.Compiled`` of an exported program's call, compiled by XLA
    in this process) at ``path``."""
    from jax.experimental import serialize_executable

    payload, in_tree, out_tree = serialize_executable.serialize(compiled)
    if (in_tree, out_tree) != _trees(n_in, out_tree.num_leaves):
        return   # not the call this module reads back
    _write(path, out_tree.num_leaves.to_bytes(4, "little") + payload, _EXECUTABLE_MAGIC)


def _program(name: str, fn: Callable, leaves, tree, compiler_options) -> Callable:
    """The compiled program of ``fn`` for these arguments: its executable read from the folder,
    or its exported program (read, or traced and written) compiled and its executable written."""
    from jax import export

    path = _FOLDER["path"] / (f"{name}-{environment_tag()}-"
                              f"{program_key(name, jax.tree.unflatten(tree, leaves))}.jaxexport")
    # executables are kept on the CPU only, where their loading was measured and tested
    executable = _executable_path(path) if jax.devices()[0].platform == "cpu" else None
    try:
        compiled = None if executable is None else _read_executable(executable, leaves)
    except Exception:  # a corrupt or foreign file: compile afresh below
        compiled = None
    if compiled is not None:
        _STATS["executables"] += 1
        return compiled
    exp = None
    try:
        exp = _read(path, leaves)
    except Exception:  # a corrupt or foreign file: export afresh below
        exp = None
    if exp is not None:
        _STATS["loaded"] += 1
    else:
        first = "the first time on this machine (or with this jaxvo and jax)" if not has_programs(path.parent) \
            else "for these images and settings"
        note_once("compiling", f"compiling jaxvo's programs {first}: seconds to a minute; later processes load "
                               f"them from {path.parent}")

        def flat(*xs):
            return tuple(jax.tree.leaves(fn(*jax.tree.unflatten(tree, xs))))
        flat.__name__ = f"{name}_exported"
        exp = export.export(jax.jit(flat))(*leaves)
        _STATS["exported"] += 1
        try:
            _write(path, bytes(exp.serialize()))
        except OSError:
            pass  # a read-only or full folder: this process still runs the program
    def run(*xs):
        return exp.call(*xs)
    # JAX's logs name the program after this function: call_<name>, not a trace of ``fn``
    run.__name__ = run.__qualname__ = f"call_{name}"
    # every input placed on the one device the program was exported for: without it an input that
    # is committed to the device in one call (e.g. a weight map computed from an earlier
    # estimate's outputs, which this program commits) and a host array in another compile the
    # whole program twice
    compiled, fresh = _compile(jax.jit(run, in_shardings=sharding(), compiler_options=compiler_options), leaves)
    # only an executable XLA compiled here: on the CPU, one that JAX read from its cache and that
    # is serialized again names kernels its file then lacks (jax 0.10: "Function ... not found")
    if fresh and executable is not None:
        try:
            _write_executable(executable, compiled, len(leaves))
        except Exception:  # noqa: BLE001 - a read-only or full folder, or a backend that cannot serialize
            pass
    return compiled


def sharding() -> jax.sharding.Sharding:
    """Where an exported program's inputs are placed and its outputs are committed: the first
    device (a caller's program that takes those outputs compiles for this sharding)."""
    return jax.sharding.SingleDeviceSharding(jax.devices()[0])


def _memo_program(name: str, fn: Callable, leaves, tree, compiler_options) -> Optional[Callable]:
    """The compiled program for these arguments in this process (:func:`_program`, at its first
    use), or None: the jit path."""
    memo = (name, tree, _signature(leaves))
    with _LOCKS_LOCK:
        lock = _LOCKS.setdefault(memo, threading.Lock())
    with lock:
        if memo not in _PROGRAMS:
            try:
                _PROGRAMS[memo] = _program(name, fn, leaves, tree, compiler_options)
            except Exception:  # e.g. flatbuffers missing, or a primitive jax.export refuses
                _PROGRAMS[memo] = None
        return _PROGRAMS[memo]


def call(name: str, fn: Callable, fn_jit: Callable, args: Tuple, compiler_options: Optional[dict] = None) -> tuple:
    """``fn(*args)``'s result leaves (a flat tuple), through the exported program kept in the
    folder (see the module docstring), or ``fn_jit(*args)``'s leaves where that is off or fails.

    fn: the Python function (traced at most once per process and program); fn_jit: its
    ``jax.jit``; compiler_options: the XLA options ``fn_jit`` was made with (the exported
    program is compiled with the same ones). ``name`` names the files (letters, digits, ``_``).
    """
    leaves, tree = jax.tree.flatten(args)
    if _FOLDER["path"] is None or any(isinstance(x, jax.core.Tracer) for x in leaves):
        return tuple(jax.tree.leaves(fn_jit(*args)))
    prog = _memo_program(name, fn, leaves, tree, compiler_options)
    if prog is not None:
        try:
            return tuple(prog(*leaves))
        except Exception:  # noqa: BLE001 - the program could not be compiled or run: use jit
            _PROGRAMS[(name, tree, _signature(leaves))] = None
    _STATS["fallbacks"] += 1
    return tuple(jax.tree.leaves(fn_jit(*args)))


def compile_ahead(name: str, fn: Callable, fn_jit: Callable, args: Tuple,
                  compiler_options: Optional[dict] = None) -> None:
    """Make :func:`call` with these arguments ready before its first call: the exported program
    read from the folder (or traced and written) and compiled, or ``fn_jit`` compiled where the
    folder is off or the program cannot be exported. ``args``' arrays may be
    ``jax.ShapeDtypeStruct``; the later call with arrays of those shapes, dtypes and weak types
    compiles nothing. Raises what lowering or compiling raises."""
    leaves, tree = jax.tree.flatten(args)
    prog = None if _FOLDER["path"] is None else _memo_program(name, fn, leaves, tree, compiler_options)
    if prog is None:   # (an exported program is compiled when it is made ready)
        fn_jit.lower(*args).compile()


def placed(tree):
    """``tree``'s arrays committed to :func:`sharding` while the folder is on (as exported
    programs leave their outputs), unchanged while it is off. For state that an exported
    program's outputs later replace: a plain jit that reads it then finds it in one placement
    (committed or not) in every call, and compiles once, not once per placement."""
    return tree if _FOLDER["path"] is None else jax.device_put(tree, sharding())


class Program:
    """A traced function run through its exported program (:func:`call`).

    name: names its files (letters, digits, ``_``); fn: the Python function; result: makes its
    result from :func:`call`'s flat tuple of leaves (default: the tuple; e.g. ``operator.itemgetter(0)``
    for a function that returns one array); compiler_options: XLA options of its jit and of the
    exported program. ``jitted`` is the plain ``jax.jit`` (the path without the folder);
    ``traces`` counts the traces of ``fn`` in this process, by either path.
    """

    def __init__(self, name: str, fn: Callable, result: Callable = tuple, compiler_options: Optional[dict] = None):
        self.name, self.fn, self.result, self.compiler_options = name, fn, result, compiler_options
        self.traces = 0

        def traced(*args):
            self.traces += 1
            return fn(*args)
        traced.__name__ = traced.__qualname__ = fn.__name__
        self.traced = traced
        self.jitted = jax.jit(traced, compiler_options=compiler_options)

    def __call__(self, *args):
        return self.result(call(self.name, self.traced, self.jitted, args, self.compiler_options))

    def compile_ahead(self, *args) -> None:
        """:func:`compile_ahead` for arguments like ``args`` (arrays may be ``jax.ShapeDtypeStruct``)."""
        compile_ahead(self.name, self.traced, self.jitted, args, self.compiler_options)
