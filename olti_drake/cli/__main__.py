"""``python -m olti_drake.cli``: the ``olti`` command."""

import sys

from olti_drake.cli import main

sys.exit(main())
