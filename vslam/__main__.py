import sys

from vslam.cli import main

sys.exit(main())
