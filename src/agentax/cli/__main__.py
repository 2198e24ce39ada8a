import sys

from agentax.cli import main

sys.exit(main())
