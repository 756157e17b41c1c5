"""Session-wide test settings."""
from __future__ import annotations

import os

import pytest

from jaxvo.runtime import cache


@pytest.fixture(scope="session", autouse=True)
def _compilation_cache_in_tmp(tmp_path_factory):
    """CLI commands run by the tests (in process and as subprocesses) keep JAX's persistent
    compilation cache in a temporary folder shared by the session, never in the user's
    ~/.cache; a test that needs its own folder sets JAXVO_CACHE_DIR itself."""
    if cache.ENV not in os.environ:
        os.environ[cache.ENV] = str(tmp_path_factory.mktemp("jax_cache"))
    yield
