"""Synthetic grasping scenes in Cornell's file layout: the project's own, unlimited data.

objects: the object catalogue and its parts; render: drawing, depth and backgrounds; grasps: the
grasp rectangles of each part; scenes: whole photos and the dataset writer (`python -m
kosmos_jax.sources.synthetic`). What they write is read back by the Cornell reader like real photos.
"""
