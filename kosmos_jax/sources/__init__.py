"""Stage 1, readers: Cornell / Jacquard folders, KOSMOS-E's annotation file and synthetic scenes in.

Gives `Photo`s (RGB, depth, grasps [N, 5] in photo pixels, object id) and the folds over photos
or objects (splits.py, with the validation split held out of a fold's training photos), decided
before any augmentation. synthetic/ makes Cornell-format scenes.
"""
