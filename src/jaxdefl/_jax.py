"""JAX set-up shared by every kernel.

- float64 everywhere: timestamps can be epoch seconds.
- a persistent compilation cache (``$JAXDEFL_CACHE_DIR``, default ``~/.cache/jaxdefl/jax``;
  set it to an empty string to disable): the CLI is a fresh process each time, and compiling
  the batched kernels costs seconds that the cache turns into milliseconds on later runs.
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
from dataclasses import replace
from functools import partial
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

_default_cache = os.path.join(os.path.expanduser("~"), ".cache", "jaxdefl", "jax")
_cache = os.environ.get("JAXDEFL_CACHE_DIR", _default_cache)
if _cache:
    try:
        os.makedirs(_cache, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", _cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    except OSError:  # a read-only home: run without the cache
        _cache = ""

__all__ = ["jax", "persistent_jit"]

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
        h.update(f"{sys.version}|{dev.platform}|{dev.device_kind}|{jax.config.jax_enable_x64}".encode())
        try:
            with open("/proc/cpuinfo", "rb") as f:
                h.update(next((ln for ln in f if ln.startswith(b"flags")), b""))
        except OSError:
            pass
        _fingerprint = h.hexdigest()
    return _fingerprint


class _PersistentJit:
    """A `jax.jit` kernel whose traced form (`jax.export.Exported`) is kept on disk per argument
    shapes, dtypes and static arguments; called exactly as the jitted function."""

    def __init__(self, fun, static_argnames: tuple[str, ...]):
        self.jitted = jax.jit(fun, static_argnames=static_argnames)
        self.name = f"{fun.__module__}.{fun.__qualname__}"
        self._loaded: dict = {}
        self._lock = threading.Lock()
        self.__doc__ = fun.__doc__
        self.__wrapped__ = fun

    def __call__(self, *args, **static):
        if not _cache:
            return self.jitted(*args, **static)
        args = tuple(a if hasattr(a, "shape") else np.asarray(a) for a in args)
        key = (
            tuple((tuple(a.shape), str(a.dtype)) for a in args),
            tuple(sorted((k, repr(v)) for k, v in static.items())),
        )
        fn = self._loaded.get(key)
        if fn is None:
            with self._lock:  # blocks on threads: one trace or load per key
                fn = self._loaded.get(key)
                if fn is None:
                    fn = self._loaded[key] = self._load(key, args, static)
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
