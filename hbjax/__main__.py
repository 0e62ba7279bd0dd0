import sys

from ._cli.parser import main


sys.exit(main())
