"""JAX set-up shared by every kernel: float64 everywhere (timestamps can be epoch seconds)."""

import jax

jax.config.update("jax_enable_x64", True)

__all__ = ["jax"]
