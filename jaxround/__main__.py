"""``python -m jaxround``: the `jaxround` command."""

import sys

from jaxround.cli import main

sys.exit(main())
