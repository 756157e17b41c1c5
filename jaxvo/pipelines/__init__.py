"""What each command does, callable from Python, each result a frozen dataclass:
:mod:`~jaxvo.pipelines.run` (one or many sequences, a rerun from a trajectory header),
:mod:`~jaxvo.pipelines.mapping` (point-cloud maps), :mod:`~jaxvo.pipelines.masks` (hindsight masks
written as PNGs), :mod:`~jaxvo.pipelines.demo` (the synthetic demo)."""
