"""``python -m zenoh_perception`` is the ``zenoh-perception`` command."""

import sys

from zenoh_perception.cli.main import main

sys.exit(main())
