"""How our kernels are compiled (``kernel``), and numba's cache of them kept in step with the
sources.

numba stamps a cached kernel with its own source file only, not with the files whose
functions it compiled in (quaternion.py, estimators/consistency.py, mahony_step in
mahony.py...). After an update that changed only those, it would load a kernel built from the
old code and give old numbers without a word. So the cache carries a stamp of every source
file that holds kernels; when the stamp differs, our cached kernels are deleted, and compile
again on first use (announced, as on a first run).
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

from numba import njit

PACKAGE = Path(__file__).resolve().parent
STAMP = "mavattitude-kernels.stamp"


def kernel(function=None, *, inline: str = "never"):
    """numba's ``njit`` as every kernel of the package takes it, ``@kernel`` or
    ``@kernel(inline="always")``: cached (compiled on a first run, loaded after), and without
    the C-callable wrapper numba builds by default (``.ctypes``, ``.address``), which nothing
    here calls: a first compile of the seven estimators takes about a tenth less CPU without it
    (in one process, four runs each: 27-33 s against 31-36 s). The CPython wrapper stays: the
    estimators and the tests call kernels from Python."""
    jit = njit(cache=True, no_cfunc_wrapper=True, inline=inline)
    return jit if function is None else jit(function)


def holds_kernels(source: bytes) -> bool:
    """Whether a source file's text defines kernels (``@kernel``, or numba's own decorator)."""
    return b"@kernel" in source or b"njit" in source


def sources_stamp(kernels_only: bool = True) -> str:
    """A hash of every package source file that defines kernels (``holds_kernels``), or of
    every one."""
    digest = hashlib.sha1()
    for path in sorted(PACKAGE.rglob("*.py")):
        text = path.read_bytes()
        if holds_kernels(text) or not kernels_only:
            digest.update(str(path.relative_to(PACKAGE)).encode() + b"\0" + text)
    return digest.hexdigest()


def cached(kernel) -> bool:
    """Whether numba's cache holds this kernel (its index file exists): if not, its first call
    compiles it. True for a function numba does not cache."""
    index = getattr(getattr(getattr(kernel, "_cache", None), "_cache_file", None), "_index_path", None)
    return index is None or os.path.exists(index)


def cache_root(kernel) -> Path | None:
    """Where numba caches this package's kernels: the package itself (a __pycache__ beside
    each module) or its mirror under NUMBA_CACHE_DIR / the user cache."""
    path = getattr(getattr(kernel, "_cache", None), "_cache_path", None)
    if path is None:
        return None
    path = Path(path)  # the cache folder of the kernel's module, in mavattitude/<sub>/
    module_dir = Path(kernel.py_func.__code__.co_filename).resolve().parent
    depth = len(module_dir.relative_to(PACKAGE).parts)
    root = path.parent if path.name == "__pycache__" else path
    for _ in range(depth):
        root = root.parent
    return root


def refresh(kernel) -> bool:
    """Empty the cache of our kernels if the sources changed since it was filled (judged by
    ``kernel``'s cache folder, one of ours); True when it did."""
    root = cache_root(kernel)
    if root is None or not root.is_dir():
        return False
    stamp_file = Path(kernel._cache._cache_path) / STAMP
    stamp = sources_stamp()
    try:
        if stamp_file.read_text() == stamp:
            return False
    except OSError:
        pass
    stale = [p for pattern in ("*.nbi", "*.nbc") for p in root.rglob(pattern)]
    for path in stale:
        try:
            path.unlink()
        except OSError:
            pass  # another process got there first, or a read-only cache: numba copes
    try:
        stamp_file.parent.mkdir(parents=True, exist_ok=True)
        tmp = stamp_file.with_suffix(f".{os.getpid()}")
        tmp.write_text(stamp)
        os.replace(tmp, stamp_file)
    except OSError:
        pass
    return bool(stale)
