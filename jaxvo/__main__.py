"""``python -m jaxvo ...`` is the same as the ``jaxvo`` command."""
from jaxvo.cli import main

if __name__ == "__main__":
    main(prog_name="jaxvo")
