"""The README's code examples run as written (on the bundled real data)."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from jaxvo.data import DatasetError, find_sequence

README = Path(__file__).resolve().parents[1] / "README.md"


def _block(heading: str) -> str:
    text = README.read_text()
    section = text.split(heading, 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_vmap_over_a_config_field():
    try:
        seq_dir = find_sequence("rgbd_dataset_freiburg2_desk")
    except DatasetError as e:
        pytest.skip(f"real data missing: {e}")
    code = _block("## A hyperparameter sweep with `jax.vmap`")
    assert "jax.vmap(motion)" in code
    # the README's relative path, as seen from the repository root
    code = code.replace('"../shared/data/tum/rgbd_dataset_freiburg2_desk"', repr(str(seq_dir)))
    ns: dict = {}
    exec(compile(code, str(README), "exec"), ns)
    T, ks = np.asarray(ns["T"]), np.asarray(ns["ks"])
    assert T.shape == (len(ks), 4, 4) and np.all(np.isfinite(T))
    # each grid value gave its own estimate, all close to one another (the same frame pair)
    t = T[:, :3, 3]
    assert np.ptp(t, axis=0).max() > 1e-6 and np.ptp(t, axis=0).max() < 0.02


def test_readme_first_screen_and_results_document():
    """Install, demo, a real-data run, the test command and where the data comes from come before
    the library reference; the result tables live in docs/results.md, linked from the README."""
    text = README.read_text()
    first = text.split("## The library in ten lines", 1)[0]
    for needle in ("pip install -e .", "jaxvo demo", "jaxvo run ../shared/data", "python -m pytest -q",
                   "cvg.cit.tum.de", "ipb.uni-bonn.de", "docs/results.md"):
        assert needle in first, needle
    results = README.parent / "docs" / "results.md"
    assert results.is_file() and "python experiments/keyframes.py" in results.read_text()
    assert "| rgbd_bonn_crowd | frame to frame |" not in text      # a result row stays out of the README


def test_library_runs_and_evaluates_without_the_cli():
    """run_sequence and evaluate are library functions: importing them loads neither jaxvo.cli.main nor click."""
    import subprocess
    import sys

    code = ("import sys, jaxvo; jaxvo.run_sequence, jaxvo.evaluate, jaxvo.open_sequence; "
            "from jaxvo.pipelines.run import run_sequence; from jaxvo.evaluation.scoring import evaluate; "
            "bad = [m for m in ('jaxvo.cli.main', 'click') if m in sys.modules]; assert not bad, bad")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]


def test_readme_paper_json_is_config_paper():
    """The fields the README tells a user to save as paper.json turn the defaults into exactly
    ``Config.paper()``: every setting where the default departs from the paper is listed there."""
    import json

    from jaxvo import Config
    section = README.read_text().split("## Where jaxvo differs from the paper and why", 1)[1]
    text = re.search(r"echo '(\{.*?\})' > paper\.json", section, re.S).group(1)
    fields = json.loads(text)
    assert Config.from_dict(fields) == Config.paper()
