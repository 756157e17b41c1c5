"""The ``jaxvo`` command line: options, one library call, printing."""
