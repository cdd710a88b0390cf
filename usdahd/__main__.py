import sys

from usdahd.cli import main

sys.exit(main())
