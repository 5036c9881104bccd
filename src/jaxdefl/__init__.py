"""jaxdefl: dynamic deflection of structures from range cameras."""

# Importing the package alone stays light (no JAX), so the CLI starts (and installs its signal
# handlers) before JAX is loaded; importing any module changes nothing in JAX: the library
# computes in float64 inside its own calls and the CLI sets it up for its process (`jaxdefl._jax`).
from ._errors import ConfigError, InputError, JaxdeflError, ParameterError

__version__ = "0.1.0"

__all__ = ["ConfigError", "InputError", "JaxdeflError", "ParameterError", "__version__"]
