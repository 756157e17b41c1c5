"""Internal: the persistent compilation cache, exported programs and the machine record (not public
API; the cache's switches are public as ``jaxvo.cache``: :func:`~jaxvo.runtime.cache.enable`,
:func:`~jaxvo.runtime.cache.disable`)."""
