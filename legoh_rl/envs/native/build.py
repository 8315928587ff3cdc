"""Build and load the native kernels (``height_march.c``: the depth camera's ray march and bilinear
lookups; ``obstacle_cast.c``: exact rays on obstacle geoms; ``body_state.c``: the env's per-step
body state; ``parallel.c``: the threads they share) with the system C compiler.

The library is compiled once per source version and machine into a cache folder
(``$LEGOH_RL_CACHE``, else ``$XDG_CACHE_HOME/legoh_rl``, else ``~/.cache/legoh_rl``) and loaded with
:mod:`ctypes`; no build step at install time and no package beyond the standard library. Where no
compiler is found or the build fails, or ``LEGOH_RL_NATIVE=0`` is set, :func:`load_library` returns
``None`` and :func:`unavailable_reason` says why; callers then use the torch implementation.

A machine without a compiler (a lent GPU machine's image) can load a library built elsewhere:
:func:`export_library` writes it into a folder under a name that hashes the sources, and
``$LEGOH_RL_NATIVE_PREBUILT`` pointing at that folder makes :func:`load_library` use it when the
name matches this source (a library of another source version is never loaded; the build on this
machine, if any, is the fallback).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

__all__ = ["SOURCES", "HEADERS", "cache_dir", "compiler", "library_path", "build_library", "load_library",
           "unavailable_reason", "source_digest", "prebuilt_name", "export_library"]

SOURCES = tuple(Path(__file__).with_name(name)
                for name in ("height_march.c", "obstacle_cast.c", "body_state.c", "parallel.c"))
HEADERS = tuple(Path(__file__).with_name(name) for name in ("parallel.h", "obstacle_cast.h", "height_map.h"))
FLAGS = ("-O3", "-fPIC", "-shared", "-pthread", "-std=c99")

_lib: ctypes.CDLL | None = None
_error: str | None = None


def cache_dir() -> Path:
    """Folder of the compiled kernels."""
    if os.environ.get("LEGOH_RL_CACHE"):
        return Path(os.environ["LEGOH_RL_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "legoh_rl"


def compiler() -> str | None:
    """The C compiler to use: ``$CC``, else the one Python was built with, else ``cc``; None if
    none of them is on the PATH."""
    candidates = [os.environ.get("CC"), (sysconfig.get_config_var("CC") or "").split(" ")[0], "cc", "gcc", "clang"]
    for c in candidates:
        if c and shutil.which(c):
            return c
    return None


def library_path(cc: str) -> Path:
    """Where the kernel built by ``cc`` from the current source is cached (the name hashes the
    source, the flags, the compiler and the platform, so an edit or another machine rebuilds)."""
    key = hashlib.sha256()
    for src in (*SOURCES, *HEADERS):
        key.update(src.read_bytes())
    key.update(" ".join((cc, *FLAGS, platform.machine(), sys.platform)).encode())
    suffix = ".dll" if sys.platform == "win32" else ".so"
    return cache_dir() / f"legoh_native-{key.hexdigest()[:16]}{suffix}"


def source_digest() -> str:
    """16 hex digits hashing the kernels' sources, the flags and the platform (not the compiler):
    a library built from this source for this platform on any machine carries it in its name."""
    key = hashlib.sha256()
    for src in (*SOURCES, *HEADERS):
        key.update(src.read_bytes())
    key.update(" ".join((*FLAGS, platform.machine(), sys.platform)).encode())
    return key.hexdigest()[:16]


def prebuilt_name() -> str:
    """File name of this source's library in a ``$LEGOH_RL_NATIVE_PREBUILT`` folder."""
    return f"legoh_native-src-{source_digest()}{'.dll' if sys.platform == 'win32' else '.so'}"


def export_library(folder: Path, cc: str | None = None) -> Path:
    """Build the kernels here (or take the cached build) and copy the library into ``folder`` as
    :func:`prebuilt_name`, for a machine without a compiler. Returns the copy.

    Raises:
        RuntimeError: no compiler here, or compiling failed.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / prebuilt_name()
    shutil.copyfile(build_library(cc), out)
    return out


def _prebuilt() -> Path | None:
    """This source's library in ``$LEGOH_RL_NATIVE_PREBUILT``, if that folder holds it."""
    folder = os.environ.get("LEGOH_RL_NATIVE_PREBUILT")
    if not folder:
        return None
    path = Path(folder) / prebuilt_name()
    return path if path.is_file() else None


def build_library(cc: str | None = None) -> Path:
    """Compile the kernel (if not cached) and return its path.

    The output is written to a temporary file and renamed into place, so concurrent processes
    never load a half-written library.

    Raises:
        RuntimeError: no compiler was found, or compiling failed (with the compiler's message).
    """
    cc = cc or compiler()
    if cc is None:
        raise RuntimeError("no C compiler found (tried $CC, Python's CC, cc, gcc, clang)")
    out = library_path(cc)
    if out.exists():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=out.stem, suffix=out.suffix, dir=out.parent)
    os.close(fd)
    try:
        cmd = [cc, *FLAGS, *map(str, SOURCES), "-o", tmp, "-lm"]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        if res.returncode != 0:
            raise RuntimeError(f"compiling {', '.join(src.name for src in SOURCES)} failed ({' '.join(cmd)}):\n{res.stderr.strip()}")
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return out


def _declare(lib: ctypes.CDLL) -> None:
    f32, f64, i64, c_int = (ctypes.POINTER(ctypes.c_float), ctypes.POINTER(ctypes.c_double),
                            ctypes.c_int64, ctypes.c_int)
    flt = ctypes.c_float
    lib.lh_march.restype = c_int
    lib.lh_march.argtypes = [f32, i64, i64, flt, flt, flt, f32, i64, f32, f32, f32, f32, f32, f32, i64, i64,
                             c_int, c_int, f64, c_int]
    u8 = ctypes.POINTER(ctypes.c_uint8)
    lib.lh_camera.restype = c_int
    vp = ctypes.c_void_p  # the obstacle geometry: ObstacleRayCaster.native_geometry's arrays
    lib.lh_camera.argtypes = [f32, f32, i64, i64, flt, flt, flt, f32, f32, i64, f32, f32, f32, f32, f32, f32, i64,
                              i64, c_int, c_int, flt, f64, u8, i64, vp, vp, vp, vp, vp, vp, vp, vp, c_int]
    i32, i64p = ctypes.POINTER(ctypes.c_int32), ctypes.POINTER(ctypes.c_int64)
    lib.lh_obstacle_cast.restype = c_int
    lib.lh_obstacle_cast.argtypes = [i64, i32, f64, f64, f64, f64, i64p, i64p, f64, i64, f64, f64, f64, f64, c_int]
    ptr = ctypes.c_void_p  # the small per-step lookups take raw addresses (array.ctypes.data): cheaper calls
    lib.lh_heights.restype = None
    lib.lh_heights.argtypes = [ptr, i64, i64, flt, flt, flt, ptr, i64, ptr]
    lib.lh_heights_around.restype = None
    lib.lh_heights_around.argtypes = [ptr, i64, i64, flt, flt, flt, ptr, ptr, ptr, i64, i64, ptr]
    lib.lh_body_state.restype = None  # (config struct, rows or NULL, n, end, out, flags)
    lib.lh_body_state.argtypes = [ptr, ptr, i64, ptr, ptr, ptr]


def _disabled() -> str | None:
    value = os.environ.get("LEGOH_RL_NATIVE", "1").strip().lower()
    return f"disabled by LEGOH_RL_NATIVE={value}" if value in ("0", "false", "no", "off") else None


def load_library() -> ctypes.CDLL | None:
    """The loaded kernel, building it on first use (or loading this source's library from
    ``$LEGOH_RL_NATIVE_PREBUILT``); None (see :func:`unavailable_reason`) when it cannot be built or loaded, or while the environment variable ``LEGOH_RL_NATIVE`` is 0 (read at
    every call). A build's outcome is remembered for the process."""
    global _lib, _error
    if _disabled():
        return None
    if _lib is None and _error is None:
        try:
            lib = ctypes.CDLL(str(_prebuilt() or build_library()))
            _declare(lib)
            _lib = lib
        except (RuntimeError, OSError, subprocess.SubprocessError) as exc:
            _error = str(exc)
    return _lib


def unavailable_reason() -> str | None:
    """Why :func:`load_library` returns None (once it was called), else None."""
    return _disabled() or (_error if _lib is None else None)
