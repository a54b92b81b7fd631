"""``python -m abm.cli`` (and ``torchrun ... -m abm.cli``): the ``abm`` command."""

import sys

from abm.cli import main

sys.exit(main())
