"""`python -m sewtol`: the same as the `sewtol` command."""

import sys

from sewtol.cli import main

sys.exit(main())
