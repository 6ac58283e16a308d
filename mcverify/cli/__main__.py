"""``python -m mcverify.cli``: the command line (as the ``mcverify`` console script)."""

import sys

from mcverify.cli import main

sys.exit(main())
