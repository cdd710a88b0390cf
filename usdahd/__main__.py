import sys

from usdahd._console import main

sys.exit(main())
