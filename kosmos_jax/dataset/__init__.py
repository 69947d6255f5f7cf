"""Stage 6, the dataset build: photos and their words in, stored INSTRUCT-GRASP splits and batches out.

views.py makes the views of each protocol (the build's and the no-learning evaluation's), samples.py
the samples of every kind, build.py drives it all (`python -m kosmos_jax.dataset.build`), writing
array_record files through tfds_builders.py; pipeline.py reads them back as grain batches.
"""
