"""JAX set-up shared by every kernel; importing it changes nothing in the JAX process.

- float64: timestamps can be epoch seconds. A library call computes in float64 inside its own
  scope, `float64()` (a context manager and decorator: `jax.enable_x64`, this thread only), so
  a process that imports jaxdefl keeps its own JAX precision. Arrays made inside a scope stay
  float64, but JAX operations on them outside it compute in float32: every function that enters
  JAX from numpy runs under `float64()` and hands numpy back (or arrays that only another scope
  reads); a thread of its own opens its own scope. The one-window kernels (`fit_harmonic`,
  `lomb_direct`, ...) compute in their caller's precision: their batched callers run them under
  `float64()`, and a kernel called directly wants `float64()` or `setup()` around it.
- `setup()`, for a process that is jaxdefl's own (the CLI): float64 for the whole process and
  the compilation cache at once.
- a persistent compilation cache (``$JAXDEFL_CACHE_DIR``, default ``~/.cache/jaxdefl/jax``;
  set it to an empty string to disable), made when a scope is first entered (or by `setup`):
  the CLI is a fresh process each time, and compiling the batched kernels costs seconds that
  the cache turns into milliseconds on later runs. A compilation cache the process configured
  itself is kept.
- `persistent_jit`: the compilation cache skips XLA's compile, not JAX's trace of the Python
  kernel (over a second for the Gauss-Newton fit, in every fresh process). The kernels of the
  fit path are therefore also kept traced (`jax.export`, one file per shape bucket in
  ``$JAXDEFL_CACHE_DIR/traced``): a later process loads the traced kernel and the compilation
  cache supplies its executable.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import sys
import threading
from contextlib import contextmanager
from dataclasses import replace
from functools import partial
from pathlib import Path

import jax
import numpy as np

__all__ = ["float64", "jax", "persistent_jit", "setup"]

_DEFAULT_CACHE = os.path.join(os.path.expanduser("~"), ".cache", "jaxdefl", "jax")
_cache: str | None = None  # the cache directory once configured; "" without a cache
_cache_lock = threading.Lock()


def _configured_cache() -> str:
    """The cache directory (made and handed to JAX's compilation cache on the first call), or ""
    when ``$JAXDEFL_CACHE_DIR`` is empty or the directory cannot be made."""
    global _cache
    if _cache is None:
        with _cache_lock:
            if _cache is None:
                path = os.environ.get("JAXDEFL_CACHE_DIR", _DEFAULT_CACHE)
                if path:
                    try:
                        os.makedirs(path, exist_ok=True)
                    except OSError:  # a read-only home: run without the cache
                        path = ""
                if path and jax.config.jax_compilation_cache_dir is None:
                    jax.config.update("jax_compilation_cache_dir", path)
                    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
                _cache = path
    return _cache


def setup() -> None:
    """Float64 for every JAX computation of this process and the compilation cache, now.

    For a process that is jaxdefl's own (the command line); idempotent. A library caller needs
    neither: every call computes in its own `float64()` scope.
    """
    jax.config.update("jax_enable_x64", True)
    _configured_cache()


@contextmanager
def float64():
    """JAX computes in float64 inside (``with float64():`` or ``@float64()``), on this thread.

    The compilation cache is configured on first use. What leaves the scope should be numpy:
    JAX operations on a float64 array outside any scope compute in float32.
    """
    _configured_cache()
    with jax.enable_x64(True):
        yield


_fingerprint: str | None = None


def _code_fingerprint() -> str:
    """What a traced kernel depends on besides its arguments: jaxdefl's source, the versions of
    Python, JAX and the libraries traced through, the backend and the host's CPU."""
    global _fingerprint
    if _fingerprint is None:
        from importlib.metadata import PackageNotFoundError, version

        h = hashlib.sha256()
        root = Path(__file__).resolve().parent
        for p in sorted(root.rglob("*.py")):
            h.update(str(p.relative_to(root)).encode())
            h.update(p.read_bytes())
        for dist in ("jax", "jaxlib", "optimistix", "lineax", "equinox"):
            try:
                h.update(f"{dist}={version(dist)}".encode())
            except PackageNotFoundError:
                h.update(dist.encode())
        dev = jax.devices()[0]
        # every kernel is traced under `float64()`, whatever the process' own setting
        h.update(f"{sys.version}|{dev.platform}|{dev.device_kind}|x64".encode())
        try:
            with open("/proc/cpuinfo", "rb") as f:
                h.update(next((ln for ln in f if ln.startswith(b"flags")), b""))
        except OSError:
            pass
        _fingerprint = h.hexdigest()
    return _fingerprint


_FIRST_CALL = threading.RLock()


class _PersistentJit:
    """A `jax.jit` kernel whose traced form (`jax.export.Exported`) is kept on disk per argument
    shapes, dtypes and static arguments; called exactly as the jitted function, in a `float64()`
    scope (its arrays go on to numpy or to another kernel)."""

    def __init__(self, fun, static_argnames: tuple[str, ...]):
        self.jitted = jax.jit(fun, static_argnames=static_argnames)
        self.name = f"{fun.__module__}.{fun.__qualname__}"
        self._loaded: dict = {}
        self.__doc__ = fun.__doc__
        self.__wrapped__ = fun

    def __call__(self, *args, **static):
        with float64():
            return self._call(args, static)

    def _call(self, args, static):
        if not _cache:
            return self.jitted(*args, **static)
        args = tuple(a if hasattr(a, "shape") else np.asarray(a) for a in args)
        key = (
            tuple((tuple(a.shape), str(a.dtype)) for a in args),
            tuple(sorted((k, repr(v)) for k, v in static.items())),
        )
        fn = self._loaded.get(key)
        if fn is None:
            # one thread at a time loads a kernel and makes its first call, which compiles it or
            # reads JAX's compilation cache: two threads reading that cache at once crashed a
            # process (a segmentation fault in `compilation_cache.get_executable_and_time`)
            with _FIRST_CALL:
                fn = self._loaded.get(key)
                if fn is None:
                    fn = self._load(key, args, static)
                    out = fn(*args)
                    self._loaded[key] = fn
                    return out
        return fn(*args)

    def _load(self, key, args, static):
        from jax import export

        digest = hashlib.sha256(repr((self.name, key, _code_fingerprint())).encode()).hexdigest()
        path = Path(_cache) / "traced" / f"{self.name}-{digest[:32]}.pkl"
        exp = None
        try:
            exp = pickle.loads(path.read_bytes())
        except Exception:  # absent, or written by something else: trace again
            exp = None
        if not isinstance(exp, export.Exported):
            spec = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in args]
            exp = export.export(jax.jit(partial(self.jitted, **static)))(*spec)
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
                tmp.write_bytes(pickle.dumps(replace(exp, _get_vjp=None)))
                os.replace(tmp, path)
            except OSError:  # a read-only cache: trace in every process
                pass
        return jax.jit(exp.call)


def persistent_jit(static_argnames: tuple[str, ...] = ()):
    """Decorator: `jax.jit` with ``static_argnames``, traced once per shape bucket on this
    machine (see the module's docstring); static arguments are passed by keyword."""
    return partial(_PersistentJit, static_argnames=tuple(static_argnames))
