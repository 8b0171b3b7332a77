"""``python -m kilonet``: the same as the ``kilonet`` command."""

import sys

from kilonet.cli import main

sys.exit(main())
