"""jaxdefl: dynamic deflection of structures from range cameras."""

from . import _jax  # noqa: F401  (float64 before any kernel is traced)
from ._errors import ConfigError, InputError, JaxdeflError

__version__ = "0.1.0"

__all__ = ["ConfigError", "InputError", "JaxdeflError", "__version__"]
