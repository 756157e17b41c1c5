"""What each command does, callable from Python, each result a frozen dataclass:
:mod:`~jaxvo.pipelines.run` (one or many sequences), :mod:`~jaxvo.pipelines.settings` (what a run
is set up with: options over a config file or an earlier trajectory's header),
:mod:`~jaxvo.pipelines.sequences` (a folder opened as ``jaxvo run`` opens it),
:mod:`~jaxvo.pipelines.mapping` (point-cloud maps), :mod:`~jaxvo.pipelines.masks` (hindsight masks
written as PNGs), :mod:`~jaxvo.pipelines.demo` (the synthetic demo)."""
