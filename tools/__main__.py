import sys

from stillpoint import main

sys.exit(main())
