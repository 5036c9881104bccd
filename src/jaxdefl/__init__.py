"""jaxdefl: dynamic deflection of structures from range cameras."""

# JAX is set up (float64, compilation cache) by `jaxdefl._jax`, imported by every module that
# builds kernels: importing the package alone stays light, so the CLI starts (and installs its
# signal handlers) before JAX is loaded.
from ._errors import ConfigError, InputError, JaxdeflError, ParameterError

__version__ = "0.1.0"

__all__ = ["ConfigError", "InputError", "JaxdeflError", "ParameterError", "__version__"]
