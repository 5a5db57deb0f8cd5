"""``python -m cape.cli``: the ``cape`` command."""

import sys

from cape.cli import main

sys.exit(main())
