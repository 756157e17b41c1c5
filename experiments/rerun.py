"""Rerun the commands that produce the numbers of ``docs/results.md``, one after the other.

Every table of ``docs/results.md`` names the command that regenerates it, in a ``bash`` block;
this script reads those blocks and runs their commands from the repository root, so that one
command reproduces (or, after a change of a default, refreshes) every result file the document
links. ``python`` is this interpreter, ``jaxvo`` this interpreter's ``python -m jaxvo``.

* ``--list`` prints the commands, numbered, with the output file each names (``--out``) and the
  wall time its last result file records (where the file says so), and runs nothing;
  ``--dry-run`` prints what the selection would run.
* ``--only 3,5`` or ``--match TEXT`` (a substring of the command line) select commands; by
  default all of them, but those that need a CUDA GPU (``experiments/gpu.py``) unless ``--gpu``.
* Each command's output goes to ``<log dir>/<NN>-<script>.log``; one line per command says its
  exit status and wall time. The first command that fails stops the run (``--keep-going``
  runs the rest) and the exit status is 1. What a finished command wrote stays.

Example::

    python experiments/rerun.py --list
    python experiments/rerun.py --match keyframes.py      # the tables of the default on real recordings
"""
from __future__ import annotations

import argparse
import re
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import List, NamedTuple, Optional

REPO = Path(__file__).resolve().parents[1]
RESULTS_MD = REPO / "docs" / "results.md"


class Command(NamedTuple):
    """One command line of a ``bash`` block: ``index`` (1-based, in document order), ``line``
    (as written, without a trailing comment), ``argv`` (to run: ``python`` and ``jaxvo`` replaced)."""
    index: int
    line: str
    argv: List[str]

    @property
    def script(self) -> str:
        """A short name: the experiment script or diagnostic, or the jaxvo command."""
        words = shlex.split(self.line)
        if words[0] == "jaxvo":
            return f"jaxvo-{words[1]}" if len(words) > 1 else "jaxvo"
        if len(words) > 2 and words[1] == "-m":
            return words[2].rsplit(".", 1)[-1]
        if len(words) > 1 and words[1].endswith(".py"):
            return Path(words[1]).stem
        return words[0]

    @property
    def out(self) -> Optional[str]:
        """The ``--out`` the line names, else None (the script's default)."""
        words = shlex.split(self.line)
        for i, w in enumerate(words):
            if w == "--out" and i + 1 < len(words):
                return words[i + 1]
            if w.startswith("--out="):
                return w.split("=", 1)[1]
        return None

    @property
    def needs_gpu(self) -> bool:
        return self.script == "gpu"


def commands(markdown: str) -> List[Command]:
    """The command lines of the ``bash`` blocks of ``markdown``, in order; ValueError naming a line
    that is neither ``python ...`` nor ``jaxvo ...``."""
    out: List[Command] = []
    for block in re.findall(r"^```bash\n(.*?)^```", markdown, re.S | re.M):
        for raw in block.splitlines():
            line = re.sub(r"\s+#.*$", "", raw).strip()   # a trailing comment (a note to the reader)
            if not line or line.startswith("#"):
                continue
            words = shlex.split(line)
            if words[0] == "python":
                argv = [sys.executable] + words[1:]
            elif words[0] == "jaxvo":
                argv = [sys.executable, "-m", "jaxvo"] + words[1:]
            else:
                raise ValueError(f"a bash block holds {line!r}: expected a 'python ...' or 'jaxvo ...' command")
            out.append(Command(len(out) + 1, line, argv))
    return out


def recorded_seconds(cmd: Command) -> Optional[float]:
    """The wall time the command's last result file records ("Total wall time N s" or "Wall time N s"),
    where its ``--out`` (or the script's usual ``experiments/results/<script>/<script>.md``) says so."""
    path = Path(cmd.out) if cmd.out else Path("experiments") / "results" / cmd.script / f"{cmd.script}.md"
    path = path if path.is_absolute() else REPO / path
    try:
        text = path.read_text()
    except OSError:
        return None
    m = re.search(r"[Ww]all time ([0-9.]+) s", text)
    return float(m.group(1)) if m else None


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--results", default=str(RESULTS_MD), help="the markdown whose bash blocks to run "
                                                               "(default docs/results.md)")
    ap.add_argument("--list", action="store_true", help="print the commands and run nothing")
    ap.add_argument("--dry-run", action="store_true", help="print what the selection would run, run nothing")
    ap.add_argument("--only", default=None, help="comma list of command numbers (as --list numbers them)")
    ap.add_argument("--match", default=None, help="only the commands whose line contains this text")
    ap.add_argument("--gpu", action="store_true", help="run the commands that need a CUDA GPU too")
    ap.add_argument("--keep-going", action="store_true", help="run the rest after a command fails")
    ap.add_argument("--log-dir", default=None, help="folder for the commands' output (default: a new "
                                                    "temporary folder, named at the start)")
    return ap.parse_args(argv)


def select(cmds: List[Command], args) -> List[Command]:
    """The commands ``--only`` / ``--match`` / ``--gpu`` select; SystemExit for a bad ``--only``."""
    chosen = cmds
    if args.only:
        try:
            wanted = {int(x) for x in args.only.split(",") if x.strip()}
        except ValueError:
            raise SystemExit(f"--only: expected comma-separated command numbers, got {args.only!r}")
        unknown = sorted(wanted - {c.index for c in cmds})
        if unknown:
            raise SystemExit(f"--only: no command numbered {unknown[0]} (1-{len(cmds)}; see --list)")
        chosen = [c for c in chosen if c.index in wanted]
    if args.match:
        chosen = [c for c in chosen if args.match in c.line]
    return chosen


def main(argv=None) -> int:
    args = parse_args(argv)
    path = Path(args.results)
    try:
        cmds = commands(path.read_text())
    except OSError as e:
        raise SystemExit(f"{path}: cannot read ({e.strerror})")
    except ValueError as e:
        raise SystemExit(f"{path}: {e}")
    if args.list:
        total = 0.0
        for c in cmds:
            sec = recorded_seconds(c)
            total += sec or 0.0
            note = (" (needs a CUDA GPU)" if c.needs_gpu else "") + (f"  [last: {sec:.0f} s]" if sec else "")
            print(f"{c.index:2d}. {c.line}{note}")
        print(f"{len(cmds)} commands; the result files that record a wall time add up to {total / 60:.0f} min")
        return 0
    chosen = select(cmds, args)
    skipped = [c for c in chosen if c.needs_gpu and not args.gpu]
    chosen = [c for c in chosen if c not in skipped]
    for c in skipped:
        print(f"{c.index:2d}. skipped (needs a CUDA GPU; --gpu runs it): {c.line}")
    if not chosen:
        print("nothing to run")
        return 0
    if args.dry_run:
        for c in chosen:
            print(f"{c.index:2d}. would run: {c.line}")
        return 0
    logs = Path(args.log_dir) if args.log_dir else Path(tempfile.mkdtemp(prefix="jaxvo-rerun-"))
    logs.mkdir(parents=True, exist_ok=True)
    print(f"logs in {logs}", flush=True)
    failed = []
    for c in chosen:
        log = logs / f"{c.index:02d}-{c.script}.log"
        t0 = time.time()
        with open(log, "w") as f:
            f.write(f"$ {c.line}\n")
            f.flush()
            rc = subprocess.run(c.argv, cwd=REPO, stdout=f, stderr=subprocess.STDOUT).returncode
        print(f"{c.index:2d}. exit {rc} in {time.time() - t0:.0f} s: {c.line}", flush=True)
        if rc != 0:
            failed.append((c, log))
            if not args.keep_going:
                break
    for c, log in failed:
        print(f"error: command {c.index} failed (exit status in its log {log})", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
