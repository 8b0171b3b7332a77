"""``python -m kilonet``: the same as the ``kilonet`` command."""

import sys

from kilonet.app.cli import main

if __name__ == "__main__":
    sys.exit(main())
