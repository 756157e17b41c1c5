"""``python -m jaxvo ...`` is the same as the ``jaxvo`` command."""
from jaxvo.cli import entry

if __name__ == "__main__":
    entry(prog_name="jaxvo")
