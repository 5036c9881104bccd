"""``python -m jaxdefl`` is the ``jaxdefl`` command."""

import sys

from .cli import main

sys.exit(main())
