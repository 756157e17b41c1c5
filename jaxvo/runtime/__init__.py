"""Internal: the persistent compilation cache, exported programs and the machine record (not public API)."""
