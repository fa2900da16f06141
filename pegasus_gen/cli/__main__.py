"""`python -m pegasus_gen.cli` (what torchrun and subprocess tests start): the `pegasus` command."""

import sys

from pegasus_gen.cli.main import main

sys.exit(main())
