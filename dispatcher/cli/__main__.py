"""``python -m dispatcher.cli``: the ``agrifleet`` command."""

import sys

from dispatcher.cli.main import main

sys.exit(main())
