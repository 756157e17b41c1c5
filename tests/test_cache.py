"""Tests of jaxvo.runtime.cache: where the persistent compilation cache lives, that a second
`jaxvo run` or library process loads the compiled estimator and tracking from it instead of
tracing and compiling again (also from a moved or copied folder), and that broken entries are
rebuilt."""
from __future__ import annotations

import json
import logging
import os
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner

from jaxvo.runtime import aot
from jaxvo.runtime import cache
from jaxvo.config import Config
from jaxvo.cli.main import main
from jaxvo.tracking import static_map, window

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
            "--max-frames", "4", "--no-progress"]


# the tracking's exported programs (besides the estimator's): the map's, made ready at the first
# frame, and the keyframe window's
TRACKING = (static_map._update_map, static_map._new_reference_map, static_map._later_motion_test, window._refine)


def test_second_run_loads_compiled_estimator_from_cache(tmp_path):
    """Two processes start together on an empty cache folder (both compile and write it), then a
    third process finds every program it needs there: it adds no entry, and traces neither the
    estimator nor the tracking's programs (the default tracking: segmentation and window)."""
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
    exported = set(os.listdir(folder / "exported"))
    assert entries - {"exported"}, "the first runs wrote no compiled program into the cache folder"
    # each program's exported (traced) program and its compiled executable: the frames' pyramid
    # (160x120 halves to 80x60: 2 levels; the classic estimate reads no depth gradients: "_d"), the
    # estimator and the tracking's
    names = sorted(["frame_pyramid_2_d", "estimate"] + [p.name for p in TRACKING])
    assert sorted(e.split("-")[0] for e in exported if e.endswith(".jaxexport")) == names
    assert sorted(e.split("-")[0] for e in exported if e.endswith(".xla")) == names

    # JAX logs each function it traces; the third process must trace no estimator
    third = subprocess.run(_cmd(seq, tmp_path / "t3.txt"), capture_output=True, text=True,
                           env={**env, "JAX_LOG_COMPILES": "1"}, cwd=REPO, timeout=600)
    assert third.returncode == 0, third.stderr
    assert "Finished tracing" in third.stderr  # the log is on (the small helpers are traced)
    traced = set(re.findall(r"Finished tracing (\S+) for", third.stderr))
    # nor does it lower them: their executables are read as they are
    assert traced and not traced & {"estimate_exported", "_estimate", "_estimate_pyramids", "call_estimate",
                                    "_frame_pyramid", "frame_pyramid", "call_frame_pyramid_2_d",
                                    *(f"{p.name}_exported" for p in TRACKING), *(p.fn.__name__ for p in TRACKING),
                                    *(f"call_{p.name}" for p in TRACKING)}
    assert set(os.listdir(folder)) == entries and set(os.listdir(folder / "exported")) == exported
    no_cache = subprocess.run(_cmd(seq, tmp_path / "t4.txt") + ["--no-cache"], capture_output=True, text=True,
                              env=env, cwd=REPO, timeout=600)
    assert no_cache.returncode == 0, no_cache.stderr
    texts = {(tmp_path / f"t{k}.txt").read_text() for k in (1, 2, 3, 4)}
    assert len(texts) == 1  # the cached and exported programs give bitwise the plain jit trajectory


def _scaled(x, config):
    return {"y": x * config.thresh_lum + config.n_points, "n": jnp.sum(x)}


_scaled_jit = jax.jit(_scaled)


@pytest.fixture
def xla_compiles():
    """JAX's persistent cache off for the test: every compilation is XLA's own (so aot writes
    each program's executable whatever other tests of the worker compiled before)."""
    before = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", None)
    yield
    jax.config.update("jax_compilation_cache_dir", before)


def _only(folder: Path, suffix: str) -> Path:
    (path,) = [p for p in folder.iterdir() if p.name.startswith("scaled") and p.name.endswith(suffix)]
    return path


def test_exported_program_is_reused_and_bad_files_fall_back(tmp_path, monkeypatch, aot_restored, xla_compiles):
    """aot.call: the first call exports the program, compiles it and writes both; a fresh start
    (the in-process memo cleared) loads the executable without tracing or compiling; a corrupt,
    truncated or foreign executable falls back to the exported program (compiled, the
    executable written again), and a bad exported program, without an executable, is replaced by a
    fresh export; an unwritable folder and traced arguments take the jit path; all give the plain
    jit result."""
    traces = []
    monkeypatch.setattr(aot, "_PROGRAMS", {})
    x = jnp.arange(6.0, dtype=jnp.float32).reshape(2, 3)
    cfg = Config(thresh_lum=2.5)
    want = jax.tree.leaves(_scaled_jit(x, cfg))

    def fn(x, config):
        traces.append(1)
        return _scaled(x, config)

    def run():
        aot._PROGRAMS.clear()  # as a new process
        before = aot.stats()
        out = aot.call("scaled", fn, _scaled_jit, (x, cfg))
        for a, b in zip(out, want):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        return {k: aot.stats()[k] - before[k] for k in before}

    def counts(executables=0, loaded=0, exported=0):
        return {"executables": executables, "loaded": loaded, "exported": exported, "fallbacks": 0}

    folder = tmp_path / "exported"
    try:
        assert aot.enable(folder) == folder
        assert run() == counts(exported=1) and len(traces) == 1
        path, xla = _only(folder, ".jaxexport"), _only(folder, ".xla")
        assert run() == counts(executables=1) and len(traces) == 1
        # the same values as NumPy (estimate_motion passes NumPy frames as they are): the same
        # program, neither a second export nor a second entry
        before = aot.stats()
        out = aot.call("scaled", fn, _scaled_jit, (np.asarray(x), cfg))
        for a, b in zip(out, want):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        assert aot.stats() == before and len(aot._PROGRAMS) == 1 and len(traces) == 1
        blob, xla_blob = path.read_bytes(), xla.read_bytes()
        for bad in (xla_blob[: len(xla_blob) // 2], xla_blob[:-1] + bytes([xla_blob[-1] ^ 1]), b"",
                    b"not an executable", blob):
            xla.write_bytes(bad)
            assert run() == counts(loaded=1)       # the exported program, compiled
            assert run() == counts(executables=1)  # its executable written again, whole
        for bad in (blob[: len(blob) // 2], blob[:-1] + bytes([blob[-1] ^ 1]), b"", b"not an exported program"):
            path.write_bytes(bad)
            xla.unlink()
            assert run() == counts(exported=1) and xla.exists()
            assert run() == counts(executables=1)  # rewritten whole
        # files of another signature under these names (e.g. copied by hand) are stale, not used
        other = aot.call("other", lambda v, c: _scaled(v, c), _scaled_jit, (x[:1], cfg))
        assert len(other) == 2
        for mine in (xla, path):
            theirs = [p for p in folder.iterdir() if p.name.startswith("other") and p.suffix == mine.suffix]
            mine.write_bytes(theirs[0].read_bytes())
        assert run() == counts(exported=1)
        # traced arguments (vmap) never use the folder
        n = len(traces)
        ys = jax.vmap(lambda t: aot.call("scaled", fn, _scaled_jit, (x, cfg.replace(thresh_lum=t)))[1])(
            jnp.array([1.0, 2.0]))  # leaves in key order: n, y
        np.testing.assert_array_equal(np.asarray(ys[1]), np.asarray(x) * 2.0 + 6)
        assert len(list(folder.iterdir())) == 4 and len(traces) == n  # the jit path
    finally:
        aot.enable(None)
    aot._PROGRAMS.clear()
    assert aot.call("scaled", fn, _scaled_jit, (x, cfg))[1].shape == (2, 3)  # off: plain jit


def test_enabling_the_folder_in_use_keeps_the_programs_ready(tmp_path, monkeypatch, aot_restored):
    """A command that switches on the folder already in use (every ``jaxvo`` command does, in
    process under click's runner or a caller's loop) reloads nothing; another folder, or none,
    starts afresh (its programs are that folder's)."""
    monkeypatch.setattr(aot, "_PROGRAMS", {})
    x = jnp.ones((2, 3), jnp.float32)
    aot.enable(tmp_path / "a")
    aot.call("scaled", _scaled, _scaled_jit, (x, Config()))
    before = aot.stats()
    assert aot.enable(tmp_path / "a") == tmp_path / "a" and len(aot._PROGRAMS) == 1
    aot.call("scaled", _scaled, _scaled_jit, (x, Config()))
    assert aot.stats() == before                     # neither loaded nor exported again
    aot.enable(tmp_path / "b")
    assert not aot._PROGRAMS
    aot.call("scaled", _scaled, _scaled_jit, (x, Config()))
    assert aot.stats()["exported"] == before["exported"] + 1 and len(list((tmp_path / "b").glob("*.jaxexport"))) == 1
    aot.enable(None)
    assert not aot._PROGRAMS and aot.folder() is None


def test_an_executable_read_from_jaxs_cache_is_not_written_again(own_cache, monkeypatch):
    """Only an executable that XLA compiled in this process is written: one that JAX's cache gave
    back names kernels that its serialization then lacks on the CPU, and a process that loaded
    it would fail. Such a program is kept as its exported program (a hit in JAX's cache) until a
    process compiles it."""
    monkeypatch.setattr(aot, "_PROGRAMS", {})
    x = jnp.arange(15.0, dtype=jnp.float32).reshape(3, 5)
    want = jax.tree.leaves(_scaled_jit(x, Config()))
    folder = own_cache / "exported"

    def run():
        aot._PROGRAMS.clear()  # as a new process
        before = aot.stats()
        out = aot.call("scaled", _scaled, _scaled_jit, (x, Config()))
        for a, b in zip(out, want):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        return {k: aot.stats()[k] - before[k] for k in before}

    assert run()["exported"] == 1
    xla = _only(folder, ".xla")
    assert run()["executables"] == 1
    xla.unlink()
    jax_entries = set(own_cache.glob("*-cache"))
    assert jax_entries                               # JAX's cache holds the compiled program
    assert run() == {"executables": 0, "loaded": 1, "exported": 0, "fallbacks": 0}
    assert not xla.exists() and set(own_cache.glob("*-cache")) == jax_entries


def test_unwritable_folder_still_runs_the_program(tmp_path, monkeypatch, aot_restored):
    monkeypatch.setattr(aot, "_PROGRAMS", {})
    folder = tmp_path / "exported"
    try:
        aot.enable(folder)

        def refuse(*args, **kwargs):
            raise PermissionError("read-only folder")
        monkeypatch.setattr(aot.os, "open", refuse)
        before = aot.stats()
        x = jnp.ones((2, 3), jnp.float32)
        out = aot.call("scaled", _scaled, _scaled_jit, (x, Config()))
        np.testing.assert_array_equal(np.asarray(out[0]), 6.0)  # n = sum(x)
        np.testing.assert_array_equal(np.asarray(out[1]), 36.0)  # y = x * 30 + 6
        assert aot.stats()["exported"] == before["exported"] + 1 and not list(folder.iterdir())
    finally:
        aot.enable(None)


def test_cli_options_choose_the_folder(tmp_path, own_cache):
    """--no-cache wins over JAXVO_CACHE_DIR; --cache-dir creates its folder (both before any
    compilation: the sequence folder is missing, so the command stops with an error)."""
    env_dir, opt_dir = tmp_path / "from_env", tmp_path / "from_option"
    runner = CliRunner(env={cache.ENV: str(env_dir)})
    r = runner.invoke(main, ["run", str(tmp_path / "missing"), "--no-cache"])
    assert r.exit_code == 2 and not env_dir.exists()
    r = runner.invoke(main, ["run", str(tmp_path / "missing"), "--cache-dir", str(opt_dir)])
    assert r.exit_code == 2 and opt_dir.is_dir() and not env_dir.exists()


# ----------------------------------------------------------------------------- the library's default

_FIRST_ESTIMATE = """
import json, sys
import jax, numpy as np
import jaxvo
from jaxvo.runtime import aot
cold = jaxvo.cache.is_cold()
rng = np.random.default_rng(0)
img = (rng.random((60, 80)) * 255).astype(np.float32)
ref = jaxvo.make_frame(img, np.full((60, 80), 2.0, np.float32))
cur = jaxvo.make_frame(np.roll(img, 1, axis=1), ref.depth)
est = jaxvo.estimate_motion(ref, cur, jaxvo.DEFAULT.at_level(3), jaxvo.Config(method="classic"), jax.random.key(0))
print(json.dumps({"folder": str(jaxvo.cache.folder()), "cold": cold, "aot": aot.stats(), "jax": jaxvo.cache.stats(),
                  "T": np.asarray(est.T_cur_ref).tolist(), "jaxopt": "jaxopt" in sys.modules,
                  "scipy_linalg": "scipy.linalg" in sys.modules}))
"""


def _first_estimate(folder: Path) -> tuple:
    r = subprocess.run([sys.executable, "-c", _FIRST_ESTIMATE], capture_output=True, text=True, cwd=REPO,
                       env={**os.environ, cache.ENV: str(folder)}, timeout=600)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.splitlines()[-1]), r.stderr


def test_a_new_library_process_reaches_its_first_estimate_without_compiling(tmp_path):
    """A program that only imports jaxvo: the first process on an empty folder compiles (and says
    so in one note line), a second one, after the folder was moved, compiles nothing: every
    program it needs is a hit, the estimator's executable is read as it is (neither traced, so
    jaxopt and the scipy it imports are never imported, nor lowered; the LAPACK kernels are made
    ready without the scipy.linalg package), and the estimate is bitwise the same."""
    first, err = _first_estimate(tmp_path / "cache")
    assert first["folder"] == str(tmp_path / "cache") and first["cold"] is True
    assert first["aot"]["exported"] == 2 and first["jax"]["requests"] > first["jax"]["hits"]  # pyramid, estimate
    assert first["jaxopt"] is True   # the trace needs it
    notes = [l for l in err.splitlines() if l.startswith("note:")]
    assert len(notes) == 1 and "compiling jaxvo's programs the first time on this machine" in notes[0]
    assert "Traceback" not in err and "Warning" not in err
    entries = sorted(p.name for p in (tmp_path / "cache").rglob("*") if p.is_file())

    shutil.move(tmp_path / "cache", tmp_path / "moved")   # a moved (or copied) folder still hits
    second, err = _first_estimate(tmp_path / "moved")
    assert second["cold"] is False and not err.strip()
    assert second["aot"] == {"executables": 2, "loaded": 0, "exported": 0, "fallbacks": 0}
    assert second["jaxopt"] is False and second["scipy_linalg"] is False
    assert second["jax"]["requests"] == second["jax"]["hits"] > 0 and second["jax"]["repaired"] == 0
    assert sorted(p.name for p in (tmp_path / "moved").rglob("*") if p.is_file()) == entries
    assert second["T"] == first["T"]


def _fresh_program(scale: float):
    """A program compiled anew in this process (a new function: JAX's in-memory caches miss, so
    the persistent cache is asked), returning its result for a fixed input."""
    return np.asarray(jax.jit(lambda x: x * scale + 1.0)(jnp.arange(4.0, dtype=jnp.float32)))


@pytest.fixture
def own_cache(tmp_path, monkeypatch):
    """This process's cache switched to an empty folder of the test, and back afterwards; the
    once-per-process notes given afresh."""
    from jaxvo.runtime import notes

    before = cache.folder()
    monkeypatch.setattr(notes, "_GIVEN", set())
    assert cache.enable(tmp_path / "cache") == tmp_path / "cache"
    yield tmp_path / "cache"
    if before is None:
        cache.disable()
    else:
        cache.enable(before)


def _entries(folder: Path):
    """The entries of :func:`_fresh_program`'s programs in ``folder``."""
    return sorted(p for p in folder.iterdir() if p.name.startswith("jit__lambda") and p.name.endswith("-cache"))


@pytest.mark.parametrize("damage", [lambda b: b[: len(b) // 2], lambda b: b"", lambda b: b"not a program"],
                         ids=["truncated", "empty", "garbage"])
def test_a_broken_entry_is_removed_and_rebuilt_with_one_note(own_cache, caplog, damage):
    want = _fresh_program(3.0)
    (entry,) = _entries(own_cache)
    good = entry.read_bytes()
    entry.write_bytes(damage(good))
    before = cache.stats()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with caplog.at_level(logging.WARNING, logger="jaxvo"):
            got = _fresh_program(3.0)     # the broken entry: removed, compiled, written anew
            _fresh_program(3.0)           # the rebuilt entry: a hit
    np.testing.assert_array_equal(got, want)
    assert not [w for w in caught if "compilation cache" in str(w.message)]   # JAX's warning is not given
    assert [r.getMessage() for r in caplog.records] == [
        f"note: {own_cache}: removed a broken compilation-cache entry (truncated or empty: a full disk or a killed "
        f"process); compiling it again"]
    after = cache.stats()
    assert after["repaired"] == before["repaired"] + 1 and after["hits"] == before["hits"] + 1
    assert after["requests"] == before["requests"] + 2 and entry.stat().st_size > len(good) // 2
    assert not [p for p in own_cache.iterdir() if p.name.endswith(".tmp")]


def test_a_copied_folder_hits_and_off_keeps_nothing(own_cache, tmp_path):
    _fresh_program(5.0)
    copy = tmp_path / "copy"
    shutil.copytree(own_cache, copy)
    assert cache.enable(copy) == copy and cache.folder() == copy
    before = cache.stats()
    _fresh_program(5.0)
    after = cache.stats()
    assert after["hits"] == before["hits"] + 1 and len(_entries(copy)) == 1
    cache.disable()
    assert cache.folder() is None and cache.is_cold() is True
    _fresh_program(7.0)
    assert len(_entries(copy)) == 1 and cache.stats()["requests"] == after["requests"] + 1


def test_import_default_follows_the_environment(own_cache, tmp_path, monkeypatch):
    """use_default (what importing jaxvo does): JAXVO_CACHE_DIR's folder, nothing for 'off', and a
    program's own JAX cache folder is left alone; a decision of the process is kept."""
    def fresh_default(env_value, jax_dir=None):
        cache.disable()
        jax.config.update("jax_compilation_cache_dir", jax_dir)
        monkeypatch.setitem(cache._STATE, "decided", False)
        monkeypatch.setenv(cache.ENV, env_value)
        return cache.use_default()

    assert fresh_default(str(tmp_path / "env")) == tmp_path / "env" == cache.folder()
    assert cache.use_default() == tmp_path / "env"          # decided: not again
    assert fresh_default("off") is None and cache.folder() is None
    assert fresh_default(str(tmp_path / "env"), jax_dir=str(tmp_path / "theirs")) is None
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "theirs") and not (tmp_path / "env2").exists()
    jax.config.update("jax_compilation_cache_dir", None)


def test_tests_do_not_write_into_the_users_cache():
    """conftest.py names a folder of the session before jaxvo is imported (what every subprocess inherits)."""
    home = cache.cache_dir(environ={"HOME": str(Path.home())})
    assert cache.ENV in os.environ and cache.cache_dir() != home
    assert cache.folder() is None or home not in (cache.folder(), *cache.folder().parents)
