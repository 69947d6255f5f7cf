"""Evaluation under the two protocols of DESIGN.md section 3: test views, baselines, fold scores."""
