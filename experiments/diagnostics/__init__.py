"""One-off investigations behind a decision (docs/decisions/) rather than a table of the docs:
run each as ``python -m experiments.diagnostics.<name>`` from the repository root."""
