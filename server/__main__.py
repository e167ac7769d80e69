"""``python -m neuronsmae.server``: the same as the ``neuronsmae-server`` console script."""

from __future__ import annotations

import sys

from neuronsmae.server.serving.cli import main

if __name__ == "__main__":
    sys.exit(main())
