import sys

from brfgs.cli import main

sys.exit(main())
