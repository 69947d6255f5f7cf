"""Facts about the full Cornell grasping set that more than one reader needs."""

# The 885 labelled photos of the full data set, sorted (KOSMOS-E's keys "0".."884" follow this).
FULL_SET_IDS: tuple[str, ...] = tuple(
    f"pcd{n:04d}" for n in [*range(100, 950), *range(1000, 1035)]
)
