"""`python -m sewtol`: the same as the `sewtol` command."""

import sys

from .cli import main

sys.exit(main())
