"""The rectangle metric, jit-compiled and vectorised: predicted and ground-truth grasps in, success out.

Used by the evaluation stage (and by training's grasp evaluation); depends on geometry only.
"""

from kosmos_jax.metrics.success import BACKENDS, WH_POLICIES, grasp_success, predicted_rectangles, rectangle_iou

__all__ = ["BACKENDS", "WH_POLICIES", "grasp_success", "predicted_rectangles", "rectangle_iou"]
