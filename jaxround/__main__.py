"""``python -m jaxround``: the `jaxround` command."""

import sys

from jaxround.apps.cli.main import main

sys.exit(main())
