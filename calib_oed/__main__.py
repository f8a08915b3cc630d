import sys

from calib_oed.cli import main

sys.exit(main())
