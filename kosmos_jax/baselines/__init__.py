"""The paper's baselines: takes photos (RGB, depth) and their folds, augmented as KOSMOS-E's views;
gives GR-ConvNet and GG-CNN2 in flax.nnx, their training targets and published losses, and one
predicted grasp per view for the rectangle metric (kosmos_jax.metrics), so both run on KOSMOS-E's folds.

Modules: grconvnet, ggcnn2 (the networks), layers (their convolutions, GraspMaps), transpose (a
transposed convolution XLA's CPU backend differentiates quickly), targets (maps from rectangles),
losses, predict (maps -> one grasp), inputs (photos + fold -> normalised views, batches), family
(what a trainer needs: init, loss sums, predictions).

The public GG-CNN / GR-ConvNet code, as described in its data loaders, grasp utilities and
evaluation, does the following; each is fixed here, with what the fix changes:
- Corners rounded to integers when read, and truncated to integers again after every rotation and
  zoom, the rectangle centre and the crop centre truncated too: every corner moves by up to half a
  pixel (more after several truncations, which all pull toward the origin), the angle of a short
  rectangle by a few degrees, the targets by a pixel. Here corners stay floats end to end
  (kosmos_jax.geometry, augment) and the targets are drawn at the exact centres.
- The "object-wise" split is contiguous blocks of the sorted file list (the list rotated by a
  fraction, then cut): blocks follow file numbers, not objects, so an object whose photos straddle a
  cut is on both sides. Here object-wise folds group photos by object id (processedData/z.txt,
  kosmos_jax.sources.splits); image-wise folds are over photos, before augmentation.
- The crops are centred on the labels: the crop window is centred on the mean of all ground-truth
  corners at training AND test time, so a test input shows the network where the answer is (the
  image centre alone then scores well). Here the honest test views are the image-centre crop, not
  rotated or shifted (inputs.fold_views); the paper protocol keeps the label-centred crops.
- The Cornell crop is clamped to a hard-coded 640 x 480 photo (a photo of another size crops wrongly); the
  photo's own size here (kosmos_jax.augment).
- The angle map is computed first (atan2 / 2) and then Gaussian-blurred: near the +-90 degree wrap a
  blur averages +89 and -89 degrees into about 0, turning a vertical grasp horizontal near its
  edges. Here cos 2 theta and sin 2 theta are blurred (sigma 2) and the angle taken after (predict).
- The peak finder (minimum distance 20 px, threshold 0.2) also excludes a 20 px border by default
  and returns no grasp when the best quality is below 0.2; such a view counts as a failure. Here the
  argmax of the blurred quality map over the whole view: always one grasp (predict).
- The metric takes the prediction's own opening, a jaw size of half of it, and an IoU counted over
  integer pixel centres that drops negative rows and columns. Here the protocol's w/h borrowing and
  the exact polygon IoU (kosmos_jax.metrics; the pixel-count IoU stays available as "reference").
- Depth is expected for every photo (Cornell's pcd0312 has no pcd0312d.tiff); here a photo without
  depth is left out of depth and RGB-D runs after the folds are drawn, and listed (inputs).
Kept as published: the targets' background angle 0 (cos 2 theta = 1 off the grasps), the 1/3
compact rectangles, the 150 px width scale, the per-crop normalisation (targets, inputs). Changed
on purpose, not a bug: the augmentation is KOSMOS-E's (crop 351, any rotation, shifts of 40 px,
crop 224) instead of quarter turns and zooms of 0.5 to 1, so the two models see the same views.
"""

from kosmos_jax.baselines.ggcnn2 import GGCNN2
from kosmos_jax.baselines.grconvnet import GRConvNet
from kosmos_jax.baselines.layers import MODES, GraspMaps, input_channels
from kosmos_jax.baselines.losses import NETWORK_LOSS, map_losses, per_image
from kosmos_jax.baselines.predict import predict_grasps
from kosmos_jax.baselines.targets import WIDTH_SCALE, grasp_maps

__all__ = ["GGCNN2", "GRConvNet", "GraspMaps", "MODES", "NETWORK_LOSS", "WIDTH_SCALE", "grasp_maps",
           "input_channels", "map_losses", "per_image", "predict_grasps"]
