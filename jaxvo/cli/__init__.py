"""The ``jaxvo`` command line: one module per command (options, one :mod:`jaxvo.pipelines` call,
printing), shared options in :mod:`jaxvo.cli.options`, process, signal and exit handling in
:mod:`jaxvo.cli.process`; :data:`jaxvo.cli.main.main` is the click group, :func:`entry` the
process entry point."""
from jaxvo.cli.process import entry

__all__ = ["entry"]
