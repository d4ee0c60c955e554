"""Give the heap memory a large build freed back to the operating system.

glibc's malloc keeps freed chunks for reuse: after loading a 2-million-triangle mesh
(trimesh's parse) or building its edge table, the process's resident size stays near
the build's peak although the temporaries are gone (180 MB after loading that mesh).
``malloc_trim(0)`` returns the free pages; elsewhere (another libc) this does nothing.
"""
from __future__ import annotations

import ctypes
import gc

try:
    _MALLOC_TRIM = ctypes.CDLL(None).malloc_trim
except (OSError, AttributeError):     # not glibc
    _MALLOC_TRIM = None


def release_freed_memory(collect: bool = False) -> None:
    """Return freed heap pages to the OS; ``collect``: first free unreachable cycles
    (trimesh's caches refer back to their mesh). Costs milliseconds: call it after a
    build, never per frame."""
    if collect:
        gc.collect()
    if _MALLOC_TRIM is not None:
        _MALLOC_TRIM(0)
