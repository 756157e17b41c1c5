"""What ``import jaxvo`` loads: the library's modules and JAX, none of the heavy optional ones.

A new process pays for every module it imports before its first pose (jaxopt with scipy costs
about as much CPU time as JAX itself); these are imported where they are used: jaxopt when the
estimator is traced (a program loaded from the cache never is), OpenCV, matplotlib, click and
Open3D by the commands, figures, readers and peers that need them.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LAZY = ("jaxopt", "scipy", "cv2", "matplotlib", "click", "open3d", "evo")

_PROBE = """
import json, sys
import jaxvo
print(json.dumps(sorted({name.split(".")[0] for name in sys.modules})))
"""


def test_import_jaxvo_loads_no_heavy_optional_module():
    r = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert r.returncode == 0, r.stderr
    loaded = set(json.loads(r.stdout.splitlines()[-1]))
    assert {"jax", "jaxvo", "numpy"} <= loaded
    assert not loaded & set(LAZY), sorted(loaded & set(LAZY))
