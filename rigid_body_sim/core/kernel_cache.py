"""
Keep numba's cache of the compiled kernels in step with their sources.

numba caches each ``@njit(cache=True)`` kernel's machine code (``*.nbi`` index,
``*.nbc`` data, next to the sources in ``__pycache__`` or in its user-wide
cache) and checks only the timestamp of the kernel's *own* source file. A kernel
that calls kernels of another module keeps their old code compiled into it when
only that other module changes (an edit, a ``git pull``): it would silently run
the old arithmetic. :func:`check` hashes the sources of all kernel modules
together with the numba version and, when the hash differs from the one stored
beside the cache, deletes the cached kernels of these modules, so that each is
compiled afresh at its first call (``python -m rigid_body_sim.core.warmup``).
It runs once, when :mod:`rigid_body_sim.core` is imported (a few milliseconds).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numba

#: The package whose compiled kernels call one another: every module of it is one unit.
KERNELS = Path(__file__).resolve().parent / 'kernels'
STAMP = 'kernel-sources.sha256'


def kernel_modules() -> list[str]:
    """Names of the modules of the kernel package (every one, found on disk)."""
    return sorted(p.stem for p in KERNELS.glob('*.py'))


def sources_digest() -> str:
    """Hash of the kernel modules' sources (names and texts) and the numba version."""
    h = hashlib.sha256(numba.__version__.encode())
    for name in kernel_modules():
        h.update(name.encode() + b'\0')
        h.update((KERNELS / f'{name}.py').read_bytes())
    return h.hexdigest()


def check(dispatcher) -> bool:
    """
    Delete the kernels' cached code if any kernel source changed since it was cached.

    ``dispatcher``: any cached kernel of the package (its modules share one cache
    directory). Returns whether stale code was deleted. Does nothing when the
    kernels are not compiled (``NUMBA_DISABLE_JIT=1``) or the cache cannot be
    written (numba then compiles in memory).
    """
    cache = getattr(dispatcher, '_cache', None)
    path = getattr(cache, '_cache_path', None)
    if path is None:
        return False
    directory = Path(path)
    digest = sources_digest()
    stamp = directory / STAMP
    try:
        if stamp.read_text() == digest:
            return False
    except OSError:
        pass
    stale = [f for name in kernel_modules() for f in directory.glob(f'{name}.*.nb[ic]')]
    try:
        for f in stale:
            f.unlink(missing_ok=True)
        directory.mkdir(parents=True, exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        return False
    return bool(stale)
