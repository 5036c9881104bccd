"""JAX set-up shared by every kernel.

- float64 everywhere: timestamps can be epoch seconds.
- a persistent compilation cache (``$JAXDEFL_CACHE_DIR``, default ``~/.cache/jaxdefl/jax``;
  set it to an empty string to disable): the CLI is a fresh process each time, and compiling
  the batched kernels costs seconds that the cache turns into milliseconds on later runs.
"""

import os

import jax

jax.config.update("jax_enable_x64", True)

_default_cache = os.path.join(os.path.expanduser("~"), ".cache", "jaxdefl", "jax")
_cache = os.environ.get("JAXDEFL_CACHE_DIR", _default_cache)
if _cache:
    try:
        os.makedirs(_cache, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", _cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    except OSError:  # a read-only home: run without the cache
        pass

__all__ = ["jax"]
