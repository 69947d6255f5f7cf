"""The rectangle metric of grasp detection, jit-compiled and vectorised."""

from kosmos_jax.metrics.success import BACKENDS, WH_POLICIES, grasp_success, predicted_rectangles, rectangle_iou

__all__ = ["BACKENDS", "WH_POLICIES", "grasp_success", "predicted_rectangles", "rectangle_iou"]
