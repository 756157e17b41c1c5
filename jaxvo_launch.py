"""Entry point of the ``jaxvo`` command: Ctrl-C while Python, JAX and OpenCV load exits 130 at once.

Importing :mod:`jaxvo.cli` loads JAX and XLA, which takes a few seconds; a KeyboardInterrupt
raised in the middle of that gives a traceback, or is swallowed by a callback inside JAX and
the command goes on. So the SIGINT handler is set before anything is imported, and
:func:`jaxvo.cli.entry` takes over from there (exit 130 and a summary on Ctrl-C).
"""
import os
import signal


def _quit_while_starting(signum, frame):
    os.write(2, b"interrupted (Ctrl-C) while starting\n")
    os._exit(130)


def main():
    signal.signal(signal.SIGINT, _quit_while_starting)
    from jaxvo.cli import entry

    signal.signal(signal.SIGINT, signal.default_int_handler)
    entry()


if __name__ == "__main__":  # pragma: no cover
    main()
