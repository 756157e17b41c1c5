"""XLA's CPU LAPACK kernels made ready, without importing the ``scipy.linalg`` package.

jaxlib's CPU Cholesky factors and triangular solves (the solvers' normal equations) call LAPACK
through the function pointers that SciPy's two Cython modules ``scipy.linalg.cython_blas`` and
``scipy.linalg.cython_lapack`` export; jaxlib's ``_lapack.initialize()`` imports those modules and
reads the pointers, once per process. JAX calls it while it lowers a program that uses them; a
program whose executable is read from a file (:mod:`jaxvo.runtime.aot`) is never lowered, so
:func:`ready` must run before it. Imported the ordinary way, the two modules first import the
whole ``scipy.linalg`` package (its array-API layer, ``numpy.f2py``): a tenth to a fifth of a
second of a warm process's start-up, for two modules that take a hundredth.

:func:`ready` therefore loads the two extension modules from their files under their own names,
lets jaxlib read them, and takes them out of ``sys.modules`` again unless the package was imported
meanwhile (then they are set on it, as an import sets them). A later ``import scipy.linalg`` (or of
either module) then runs as it always does and finds the same module objects: a Cython module
keeps its one module object per process and returns it when it is imported again. Any surprise
(no SciPy, another layout, another jaxlib) takes the ordinary path.
"""
from __future__ import annotations

import glob
import importlib.machinery
import importlib.util
import os
import sys
import threading

__all__ = ["ready"]

_STATE = {"ready": False}
_LOCK = threading.Lock()
_MODULES = ("cython_blas", "cython_lapack")   # in this order: cython_lapack's init reads cython_blas


def _extension_path(package_dir: str, name: str) -> str:
    """The file of extension module ``name`` in ``package_dir`` (the interpreter's suffixes, in
    its order of preference); KeyError if there is none."""
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        found = glob.glob(os.path.join(glob.escape(package_dir), name + suffix))
        if found:
            return found[0]
    raise KeyError(name)


def _load_by_file(added: dict) -> None:
    """SciPy's two Cython LAPACK modules, loaded from their files into ``sys.modules`` (those not
    there yet); each one added is also put in ``added``, by full name."""
    spec = importlib.util.find_spec("scipy")   # a top-level name: found, not imported
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("scipy")
    linalg = os.path.join(list(spec.submodule_search_locations)[0], "linalg")
    for name in _MODULES:
        full = f"scipy.linalg.{name}"
        if full in sys.modules:
            continue
        mod_spec = importlib.util.spec_from_file_location(full, _extension_path(linalg, name))
        module = importlib.util.module_from_spec(mod_spec)
        mod_spec.loader.exec_module(module)
        sys.modules[full] = added[full] = module


def _initialize() -> None:
    from jax._src.lib import lapack

    lapack._lapack.initialize()


def ready() -> None:
    """Point XLA's CPU LAPACK kernels at SciPy's LAPACK (idempotent, thread-safe). Call it before
    the first executable that may call them is loaded; lowering does it by itself."""
    if _STATE["ready"]:
        return
    with _LOCK:
        if _STATE["ready"]:
            return
        added = {}
        try:
            if "scipy.linalg" not in sys.modules:
                _load_by_file(added)
            _initialize()
        except Exception:  # noqa: BLE001 - another SciPy or jaxlib: the ordinary imports
            _ordinary()
        finally:
            _put_back(added)
        _STATE["ready"] = True


def _put_back(added: dict) -> None:
    """Leave ``sys.modules`` as an ordinary import would: the modules set on ``scipy.linalg`` if
    it was imported meanwhile, else out of ``sys.modules`` (the package imports them anew)."""
    package = sys.modules.get("scipy.linalg")
    for full, module in added.items():
        if package is not None:
            setattr(package, full.rsplit(".", 1)[1], module)
        elif sys.modules.get(full) is module:
            del sys.modules[full]


def _ordinary() -> None:
    try:
        _initialize()
    except Exception:  # noqa: BLE001 - a jaxlib without it: lowering any LAPACK call does it
        import jax
        import numpy as np

        jax.jit(jax.numpy.linalg.cholesky).lower(np.eye(2, dtype=np.float32))
