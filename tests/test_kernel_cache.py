"""numba's cache is emptied of our kernels when any kernel source changed (kernel_cache)."""
from __future__ import annotations

from types import SimpleNamespace

from mavattitude import kernel_cache
from mavattitude.estimators.mahony import mahony_run


def fake_kernel(cache_dir):
    """A kernel of estimators/mahony.py whose cache lives in ``cache_dir`` (a NUMBA_CACHE_DIR mirror)."""
    return SimpleNamespace(_cache=SimpleNamespace(_cache_path=str(cache_dir)), py_func=mahony_run.py_func)


def test_a_changed_source_empties_the_cache_once(tmp_path, monkeypatch):
    mirror = tmp_path / "mavattitude"
    (mirror / "estimators").mkdir(parents=True)
    kernel = fake_kernel(mirror / "estimators")
    assert kernel_cache.cache_root(kernel) == mirror
    old = [mirror / "estimators" / "eq_kf.eqkf_run-1.py311.nbi", mirror / "quaternion.rotate-2.py311.1.nbc"]
    for path in old:
        path.write_bytes(b"x")
    keep = mirror / "notes.txt"
    keep.write_text("not a kernel")
    assert kernel_cache.refresh(kernel)  # no stamp yet: whatever is there may be stale
    assert not any(p.exists() for p in old) and keep.exists()
    old[0].write_bytes(b"x")
    assert not kernel_cache.refresh(kernel) and old[0].exists()  # same sources: kept
    monkeypatch.setattr(kernel_cache, "sources_stamp", lambda: "changed")
    assert kernel_cache.refresh(kernel) and not old[0].exists()


def test_the_stamp_covers_the_inlined_helpers():
    """quaternion.py and estimators/consistency.py are compiled into other modules' kernels."""
    import hashlib

    stamp = kernel_cache.sources_stamp()
    assert len(stamp) == 40 and stamp == kernel_cache.sources_stamp()
    files = {str(p.relative_to(kernel_cache.PACKAGE)) for p in kernel_cache.PACKAGE.rglob("*.py")
             if b"njit" in p.read_bytes()}
    assert {"quaternion.py", "estimators/consistency.py", "estimators/mahony.py"} <= files
    assert hashlib.sha1(b"").hexdigest() != stamp
