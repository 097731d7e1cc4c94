"""``python -m so3jax.commands``: the ``so3jax`` command line."""

import sys

from so3jax.commands import main

sys.exit(main())
