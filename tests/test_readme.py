"""The README is a short user's guide whose code runs as written (on the bundled real data)."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from jaxvo.data import DatasetError, find_sequence

README = Path(__file__).resolve().parents[1] / "README.md"
ROOT = README.parent
DATA_PREFIX = "../shared/data/"
MAX_LINES = 250


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), re.S)


def test_readme_is_short():
    """A user's guide, not a notebook: the README fits in MAX_LINES lines."""
    n = len(README.read_text().splitlines())
    assert n <= MAX_LINES, f"README.md has {n} lines, at most {MAX_LINES}"


def test_readme_python_blocks_run(tmp_path, monkeypatch):
    """Every Python block runs as written, in order and in one namespace (the streaming block goes
    on from the library block), on the bundled real data; files they write land in tmp_path."""
    try:
        data = find_sequence("rgbd_dataset_freiburg2_desk").parents[1]
    except DatasetError as e:
        pytest.skip(f"real data missing: {e}")
    blocks = _python_blocks()
    assert len(blocks) >= 3
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    for code in blocks:
        # the README's relative paths, as seen from the repository root
        code = code.replace(f'"{DATA_PREFIX}', f'"{data}/')
        exec(compile(code, str(README), "exec"), ns)
    # the library block: a trajectory of every frame, written to disk
    poses = np.asarray(ns["traj"].poses)
    assert poses.shape[1:] == (4, 4) and np.all(np.isfinite(poses))
    assert (tmp_path / "traj.txt").is_file()
    # the streaming block: Odometry.add gives the poses track gives
    assert np.allclose(np.asarray(ns["step"].T_world_cur), poses[-1], atol=1e-9)
    # the sweep block: each grid value gave its own estimate, all close (the same frame pair)
    T, ks = np.asarray(ns["T"]), np.asarray(ns["ks"])
    assert T.shape == (len(ks), 4, 4) and np.all(np.isfinite(T))
    t = T[:, :3, 3]
    assert np.ptp(t, axis=0).max() > 1e-6 and np.ptp(t, axis=0).max() < 0.02


def test_readme_first_screen_and_results_document():
    """Install, demo and the test command are on the first screen; a real-data run and where the
    data comes from come before the library reference; the result tables live in
    docs/results.md, linked from the README."""
    text = README.read_text()
    first_screen = "\n".join(text.splitlines()[:40])
    for needle in ("pip install -e .", "jaxvo demo", "python -m pytest -q"):
        assert needle in first_screen, needle
    first = text.split("## The library in ten lines", 1)[0]
    for needle in ("jaxvo run ../shared/data", "jaxvo eval", "cvg.cit.tum.de", "ipb.uni-bonn.de", "docs/results.md"):
        assert needle in first, needle
    assert "docs/decisions/" in text
    results = ROOT / "docs" / "results.md"
    assert results.is_file() and "python experiments/keyframes.py" in results.read_text()
    assert "| rgbd_bonn_crowd | frame to frame |" not in text      # a result row stays out of the README


def test_readme_test_command_is_the_ci_command():
    """The README's test command is the one `.ci/run` runs."""
    assert 'pip install -e ".[test]" && python -m pytest -q' in README.read_text()
    assert "python -m pytest -q" in (ROOT / ".ci" / "run").read_text()


def test_readme_has_no_history():
    """No clock times, dates or commit hashes in the user's guide (history lives in docs/decisions/ and git)."""
    text = README.read_text()
    assert not re.search(r"\b\d{1,2}:\d{2} UTC\b", text)
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text)
    assert not re.search(r"\bcommit [0-9a-f]{7,40}\b|\bat [0-9a-f]{7}\b", text)


def _help(*command: str) -> str:
    """``jaxvo COMMAND --help``'s text, from the command group in this process (click's runner: the
    same text as the installed entry point's, without a new interpreter per command)."""
    from click.testing import CliRunner

    from jaxvo.cli.main import main

    r = CliRunner().invoke(main, [*command, "--help"], prog_name="jaxvo")
    assert r.exit_code == 0, r.output[-2000:]
    return r.stdout


def test_readme_commands_exist():
    """Every `jaxvo <command>` the README names is a command, and the options on its command lines
    (the shell blocks and the command table) are options of that command."""
    text = README.read_text()
    commands = set(re.findall(r"^  (\w+)  ", _help().split("Commands:", 1)[1], re.M))
    shell = "\n".join(re.findall(r"```bash\n(.*?)```", text, re.S))
    named = set(re.findall(r"`jaxvo (\w+)", text)) | set(re.findall(r"^jaxvo (\w+)", shell, re.M))
    assert named <= commands, named - commands
    table = re.search(r"\| command \| what it does \|\n(.*?)\n\n", text, re.S).group(1)
    assert {re.match(r"\| `jaxvo (\w+)", row).group(1) for row in table.splitlines()[1:]} == commands
    lines = [ln for ln in (shell + "\n" + table).splitlines() if re.search(r"\bjaxvo \w+", ln)]
    wanted: dict[str, set] = {}
    for ln in lines:
        cmd = re.search(r"\bjaxvo (\w+)", ln).group(1)
        wanted.setdefault(cmd, set()).update(re.findall(r"(?<![\w-])(--?[a-z][a-z-]*)", ln.split("#")[0]))
    for cmd, options in wanted.items():
        help_text = _help(cmd)
        for opt in options:
            assert re.search(rf"(?<![\w-]){re.escape(opt)}(?![\w-])", help_text), (cmd, opt)


def test_results_links_resolve():
    """Every experiments/results/<script>/<file> that the README or docs/results.md links exists, and
    <script> is an experiments script or diagnostic (one folder of results per script)."""
    for doc in (README, ROOT / "docs" / "results.md"):
        for script in re.findall(r"python (experiments/[\w/]+\.py)", doc.read_text()):
            assert (ROOT / script).is_file(), (doc.name, script)
    if not (ROOT / "experiments" / "results" / "keyframes").is_dir():
        pytest.skip("experiments/results/ is not yet one folder per script")
    for doc in (README, ROOT / "docs" / "results.md"):
        for rel in re.findall(r"experiments/results/([\w-]+)/([\w.-]+\.(?:md|png|json))", doc.read_text()):
            script, name = rel
            # a script of experiments/ or of its diagnostics (python -m experiments.diagnostics.<script>)
            assert any((ROOT / "experiments" / sub / f"{script}.py").is_file() for sub in ("", "diagnostics")), \
                (doc.name, script)
            assert (ROOT / "experiments" / "results" / script / name).is_file(), (doc.name, "/".join(rel))


def test_library_runs_and_evaluates_without_the_cli():
    """run_sequence and evaluate are library functions: importing them loads neither jaxvo.cli.main nor click."""
    import subprocess
    import sys

    code = ("import sys, jaxvo; jaxvo.run_sequence, jaxvo.evaluate, jaxvo.open_sequence; "
            "from jaxvo.pipelines.run import run_sequence; from jaxvo.evaluation.scoring import evaluate; "
            "bad = [m for m in ('jaxvo.cli.main', 'click') if m in sys.modules]; assert not bad, bad")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]


def test_readme_paper_table_is_config_paper():
    """The README's table of departures from the paper, its "the paper" column applied to the
    defaults, gives exactly ``Config.paper()``: every such setting is listed there."""
    import json

    from jaxvo import Config
    section = README.read_text().split("## The method, and where it departs from the paper", 1)[1]
    rows = re.findall(r"^\| `(\w+)` \| `([^`]*)` \| `([^`]*)` \|", section, re.M)
    assert len(rows) >= 9
    paper = {name: json.loads(value) for name, value, _ in rows}
    default = {name: json.loads(value) for name, _, value in rows}
    assert Config.from_dict(paper) == Config.paper()
    assert Config.from_dict(default) == Config()
