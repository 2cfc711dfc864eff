"""``python -m asap_dsl.cli``: the same entry point as the ``asapc`` command."""

import sys

from asap_dsl.cli import main

sys.exit(main())
