"""Scripts that regenerate the numbers the documentation quotes (``python experiments/<name>.py``,
from the repository root); ``diagnostics/`` holds one-off investigations (``python -m
experiments.diagnostics.<name>``). Outputs go to ``experiments/results/<name>/``."""
