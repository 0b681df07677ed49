import sys

from lde.cli import main

sys.exit(main())
