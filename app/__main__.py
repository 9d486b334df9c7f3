"""``python -m app``: the ``skelasm`` command line, as installed by the package."""

import sys

from app.cli import main

sys.exit(main())
