import sys

from usdahd.console import main

sys.exit(main())
