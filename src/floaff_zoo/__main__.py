import sys

from floaff_zoo.cli import main

sys.exit(main())
