"""python -m kmpipe"""

import sys

from kmpipe.cli import main

sys.exit(main())
