"""Process, signal and exit handling of the ``jaxvo`` command, in one place.

* :func:`entry`: the process entry point: the command, then an immediate ``os._exit`` with its
  status once Python's own threads are done;
* :class:`Group`: click's usage errors as one ``error:`` line and exit code 2, Ctrl-C as exit 130;
* :func:`handle_errors`: bad input (DatasetError, ValueError, OSError, :class:`Fail`) as one
  ``error: <file>: <problem>`` line on stderr and exit code 2, never a traceback;
* :class:`CtrlC`: a long job that runs JAX in a worker thread, so Ctrl-C is noticed at once.
"""
from __future__ import annotations

import functools
import os
import signal
import sys
import threading
from typing import Callable

import click

from jaxvo.data import DatasetError
from jaxvo.pipelines.messages import one_line, one_line_text

__all__ = ["Fail", "handle_errors", "exit_now", "entry", "Group", "ignore_ctrl_c", "quiet_native_stderr", "CtrlC"]


class Fail(Exception):
    """Raised to end a command with ``error: message`` and exit code 2."""


def handle_errors(f):
    """Turn DatasetError / ValueError / OSError (bad input) into ``error: ...`` and exit code 2."""
    @functools.wraps(f)
    def wrapper(*args, **kwargs):
        try:
            return f(*args, **kwargs)
        except (Fail, DatasetError, ValueError, OSError) as e:
            click.echo(f"error: {one_line(e)}", err=True)
            sys.exit(2)
    return wrapper


def exit_now(code: int) -> None:
    """Flush and leave at once, skipping interpreter teardown (which can crash while XLA is busy)."""
    for f in (sys.stdout, sys.stderr):
        try:
            f.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def entry(prog_name: str = "jaxvo") -> None:
    """The process entry point (``jaxvo``, ``python -m jaxvo``): the command, then, once the
    threads Python would wait for are done (the segmentation's programs compiled ahead), a flush
    and an immediate exit with the command's status. The interpreter's own teardown destroys
    XLA's runtime while its native threads may still be busy, and can then abort ("terminate
    called after throwing an instance of ''") after every output was written."""
    from jaxvo.cli.main import main

    code = 0
    try:
        main.main(prog_name=prog_name)
    except SystemExit as e:
        if isinstance(e.code, str):
            click.echo(e.code, err=True)
            code = 1
        else:
            code = 0 if e.code is None else int(e.code)
    for t in threading.enumerate():
        if t is not threading.main_thread() and not t.daemon:
            t.join()
    exit_now(code)


class Group(click.Group):
    """The ``jaxvo`` group: click's usage errors as one ``error:`` line (exit 2), Ctrl-C as exit 130."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        quiet_native_stderr()
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.UsageError as e:
            hint = f" (see '{e.ctx.command_path} --help')" if e.ctx is not None else ""
            click.echo(f"error: {one_line_text(e.format_message())}{hint}", err=True)
            sys.exit(2)
        except click.ClickException as e:
            click.echo(f"error: {one_line_text(e.format_message())}", err=True)
            sys.exit(2)
        except (click.Abort, KeyboardInterrupt):
            ignore_ctrl_c()
            click.echo("interrupted (Ctrl-C); unfinished outputs keep their .partial names", err=True)
            exit_now(130)
        if not standalone_mode:
            return rv
        sys.exit(rv if isinstance(rv, int) else 0)


def ignore_ctrl_c() -> None:
    """While we report an interrupt and leave, a second Ctrl-C must not end in a traceback."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def quiet_native_stderr() -> None:
    """Send what C libraries write straight to file descriptor 2 (libpng's and OpenCV's warnings
    about a damaged PNG, XLA's log lines) to /dev/null, keeping Python's ``sys.stderr`` (our
    messages, the progress bar) on the real stderr, so a bad file gives one ``error:`` line and
    nothing before it. Only for a real terminal/pipe stderr; ``JAXVO_NATIVE_STDERR=1`` keeps it."""
    os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
    if os.environ.get("JAXVO_NATIVE_STDERR") or sys.stderr is not sys.__stderr__:
        return
    try:
        if sys.stderr.fileno() != 2:
            return
        sys.stderr.flush()
        keep = os.dup(2)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 2)
        os.close(devnull)
    except (AttributeError, ValueError, OSError):
        return
    sys.stderr = os.fdopen(keep, "w", buffering=1, encoding=sys.__stderr__.encoding or "utf-8",
                           errors="backslashreplace")


class CtrlC:
    """Ctrl-C for a long job that runs JAX: the job runs in a worker thread and SIGINT only sets a
    flag, so the main thread notices at once even while XLA compiles (which no Python signal
    handler can interrupt). The job checks :meth:`check` between steps and ends cleanly; a job
    that does not get there within ``grace`` seconds (still compiling) is abandoned:
    ``on_abandon()`` reports, and the process exits 130 without tearing XLA down."""

    def __init__(self, grace: float = 3.0):
        self.flag = threading.Event()
        self.grace = grace

    def check(self, *_) -> None:
        if self.flag.is_set():
            raise KeyboardInterrupt

    @property
    def interrupted(self) -> bool:
        """Ctrl-C was pressed (also when the job finished before it noticed)."""
        return self.flag.is_set()

    def run(self, fn: Callable, on_abandon: Callable[[], None] = lambda: None):
        if threading.current_thread() is not threading.main_thread():
            return fn()
        box = {}

        def target():
            try:
                box["value"] = fn()
            except BaseException as e:  # re-raised in the main thread
                box["error"] = e
        worker = threading.Thread(target=target, name="jaxvo-job", daemon=True)
        old = signal.signal(signal.SIGINT, lambda signum, frame: self.flag.set())
        try:
            worker.start()
            while worker.is_alive() and not self.flag.is_set():
                worker.join(0.1)
            if worker.is_alive():
                worker.join(self.grace)
                if worker.is_alive():
                    ignore_ctrl_c()
                    on_abandon()
                    exit_now(130)
        finally:
            signal.signal(signal.SIGINT, signal.SIG_IGN if self.flag.is_set() else old)
        if "error" in box:
            raise box["error"]
        return box["value"]
