"""`python -m kosmos_jax.sources.synthetic`: write a synthetic Cornell-format dataset (see scenes.py)."""

import sys

from kosmos_jax.sources.synthetic.scenes import main

sys.exit(main())
