"""Write tests/fixtures/kosmos2_tiny/: a tiny random PyTorch KOSMOS-2 of transformers, its inputs and outputs.

    .venv/bin/pip install torch==2.13.0 'transformers>=5,<6'   # the `parity` extra
    .venv/bin/python scripts/make_parity_fixture.py

The normal test suite reads this fixture with our torch-free importer (tests/test_model_parity.py).
"""

import argparse
import pathlib

import numpy as np

from kosmos_jax.models.parity import make_reference

FIXTURE = pathlib.Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "kosmos2_tiny"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, default=FIXTURE)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    arrays = make_reference(args.out, seed=args.seed)
    np.savez_compressed(args.out / "reference.npz", **arrays)
    total = sum(p.stat().st_size for p in args.out.iterdir())
    print(f"wrote {sorted(p.name for p in args.out.iterdir())} to {args.out} ({total / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()
