import sys

from streamid.cli import main

sys.exit(main())
