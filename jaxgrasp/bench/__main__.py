import sys

from jaxgrasp.bench import main

sys.exit(main())
