import sys

from jaxhumanoid.outputs.cli import main

sys.exit(main())
