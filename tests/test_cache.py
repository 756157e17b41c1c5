"""Tests of jaxvo.cache: where the persistent compilation cache lives, and that a second
`jaxvo run` process loads the compiled estimator from it instead of compiling again."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from click.testing import CliRunner

from jaxvo import cache
from jaxvo.cli import main

REPO = Path(__file__).resolve().parents[1]


def test_cache_dir_precedence(tmp_path):
    home = {"HOME": str(tmp_path / "home")}
    assert cache.cache_dir(environ=home) == tmp_path / "home" / ".cache" / "jaxvo"
    xdg = {**home, "XDG_CACHE_HOME": str(tmp_path / "xdg")}
    assert cache.cache_dir(environ=xdg) == tmp_path / "xdg" / "jaxvo"
    assert cache.cache_dir(environ={**xdg, "XDG_CACHE_HOME": ""}) == tmp_path / "home" / ".cache" / "jaxvo"
    env = {**xdg, cache.ENV: str(tmp_path / "mine")}
    assert cache.cache_dir(environ=env) == tmp_path / "mine"
    for off in ("", "0", "off", "OFF", "false", "no"):
        assert cache.cache_dir(environ={**xdg, cache.ENV: off}) is None
    # the options win over the environment
    assert cache.cache_dir(tmp_path / "opt", environ=env) == tmp_path / "opt"
    assert cache.cache_dir(tmp_path / "opt", disabled=True, environ=env) is None
    assert cache.cache_dir(disabled=True, environ=home) is None


def test_enable_unwritable_folder_is_refused(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert cache.enable(blocker / "cache") is None
    assert cache.enable(None) is None


def _cmd(seq: Path, out: Path):
    return [sys.executable, "-m", "jaxvo", "run", str(seq), "--out", str(out), "--method", "classic",
            "--max-frames", "4", "--frame-to-frame", "--no-progress"]


def test_second_run_loads_compiled_estimator_from_cache(tmp_path):
    """Two processes start together on an empty cache folder (both compile and write it), then a
    third process finds every program it needs there: it adds no entry."""
    seq = tmp_path / "seq"
    r = CliRunner().invoke(main, ["synth", "seq1", str(seq), "--frames", "5", "--size", "160x120",
                                  "--no-progress"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    folder = tmp_path / "jax_cache"
    env = {**os.environ, cache.ENV: str(folder)}

    procs = [subprocess.Popen(_cmd(seq, tmp_path / f"t{k}.txt"), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=env, cwd=REPO) for k in (1, 2)]
    for p in procs:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
        assert "device cpu:0" in err or "device gpu:0" in err
        assert "Traceback" not in err
    entries = set(os.listdir(folder))
    assert entries, "the first runs wrote no compiled program into the cache folder"

    third = subprocess.run(_cmd(seq, tmp_path / "t3.txt"), capture_output=True, text=True, env=env, cwd=REPO,
                           timeout=600)
    assert third.returncode == 0, third.stderr
    assert set(os.listdir(folder)) == entries
    texts = {(tmp_path / f"t{k}.txt").read_text() for k in (1, 2, 3)}
    assert len(texts) == 1  # the cached programs give the same trajectory


def test_cli_options_choose_the_folder(tmp_path):
    """--no-cache wins over JAXVO_CACHE_DIR; --cache-dir creates its folder (both before any
    compilation: the sequence folder is missing, so the command stops with an error)."""
    env_dir, opt_dir = tmp_path / "from_env", tmp_path / "from_option"
    runner = CliRunner(env={cache.ENV: str(env_dir)})
    r = runner.invoke(main, ["run", str(tmp_path / "missing"), "--no-cache"])
    assert r.exit_code == 2 and not env_dir.exists()
    r = runner.invoke(main, ["run", str(tmp_path / "missing"), "--cache-dir", str(opt_dir)])
    assert r.exit_code == 2 and opt_dir.is_dir() and not env_dir.exists()
