import sys

from usdahd.web import main

sys.exit(main())
