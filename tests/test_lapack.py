"""jaxvo.runtime.lapack: XLA's CPU LAPACK kernels made ready from SciPy's two Cython modules,
loaded by file, without the scipy.linalg package; a later import of SciPy is as ever."""
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

_SCRIPT = r"""
import json, sys
import numpy as np, jax, jax.numpy as jnp
from jaxvo.runtime import lapack
lapack.ready()
before = sorted(m for m in sys.modules if m.startswith("scipy.linalg"))
a = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]], np.float32)
b = np.array([1.0, -2.0, 0.5], np.float32)
x = jax.jit(lambda a, b: jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(a), b))(a, b)
import scipy.linalg.cython_blas as blas
import scipy.linalg
print(json.dumps({"before": before, "x": np.asarray(x).tolist(), "expected": np.linalg.solve(a.astype(np.float64), b).tolist(),
                  "attribute": scipy.linalg.cython_blas is blas and scipy.linalg.cython_lapack.__name__,
                  "capi": "dgemm" in blas.__pyx_capi__,
                  "scipy": scipy.linalg.cho_solve(scipy.linalg.cho_factor(a.astype(np.float64)), b).tolist()}))
"""


def test_lapack_is_ready_without_importing_scipy_linalg_and_scipy_imports_as_ever():
    r = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.splitlines()[-1])
    assert out["before"] == []   # neither the package nor the two modules are left in sys.modules
    assert max(abs(x - e) for x, e in zip(out["x"], out["expected"])) < 1e-5   # the kernels are SciPy's LAPACK
    assert out["attribute"] == "scipy.linalg.cython_lapack" and out["capi"] is True
    assert max(abs(x - e) for x, e in zip(out["scipy"], out["expected"])) < 1e-12
