import sys

from camnet.cli import main

sys.exit(main())
