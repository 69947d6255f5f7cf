"""`python -m kosmos_jax.data.synthetic`: write a synthetic Cornell-format dataset (see scenes.py)."""

import sys

from kosmos_jax.data.synthetic.scenes import main

sys.exit(main())
