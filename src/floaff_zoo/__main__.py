import sys

from floaff_zoo.cli import main

if __name__ == "__main__":  # `python -m floaff_zoo`; importing the module runs nothing
    sys.exit(main())
