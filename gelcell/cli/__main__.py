"""``python -m gelcell.cli``: the ``gelcell`` command."""

import sys

from gelcell.cli import main

sys.exit(main())
