"""`python -m cq_ros.cli`: the `cq-ros` command, as the launcher re-executes it on another host."""

import sys

from .main import main

sys.exit(main())
