import sys

from zdrone.cli import main

sys.exit(main())
