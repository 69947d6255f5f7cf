"""The paper's baselines: takes photos (RGB, depth) and their folds, augmented as KOSMOS-E's views;
gives GR-ConvNet and GG-CNN2 in flax.nnx, their training targets and published losses, and one
predicted grasp per view for the rectangle metric (kosmos_jax.metrics), so both run on KOSMOS-E's folds.

Modules: grconvnet, ggcnn2 (the networks), layers (their convolutions, GraspMaps), transpose (a
transposed convolution XLA's CPU backend differentiates quickly), targets (maps from rectangles),
losses, predict (maps -> one grasp), public_detect (maps -> one grasp or none, as the public code
finds it), inputs (photos + fold -> normalised views, batches), family (what a trainer needs: init,
loss sums, predictions).

The public GG-CNN / GR-ConvNet code, as described in its data loaders, grasp utilities and
evaluation, does the following; each is fixed here under the honest and paper protocols, with what
the fix changes (the `public` protocol, below, puts the evaluation's part back):
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

The public protocol
-------------------
`protocol="public"` (config data.protocol, inputs.fold_views, train.baseline_task.test_scores,
`python -m kosmos_jax.evaluate`) scores a baseline as GR-ConvNet's and GG-CNN's own code does, so
that their published Cornell figures (DESIGN.md section 3) can be set beside ours. From
skumra/robotic-grasping (train_network.py, evaluate.py, utils/data/cornell_data.py and
grasp_data.py, inference/post_process.py, utils/dataset_processing/grasp.py and evaluation.py) and
dougsm/ggcnn (train_ggcnn.py, eval_ggcnn.py, models/common.py, the same data and grasp utilities):
- Split (sources.splits.public_split): ONE split of the sorted photo list (their sorted
  `*/pcd*cpos.txt`): the first floor(0.9 n) photos train, the rest test (`--split 0.9`). Scheme
  "image" shuffles the indices first as `--ds-shuffle --random-seed 123` does (numpy's legacy
  `np.random.seed(123); np.random.shuffle`; their released model is named "cornell-randsplit-...");
  scheme "object" does not shuffle: the last tenth of the file list, their default, the only split
  of train_ggcnn.py and the photos evaluate.py and eval_ggcnn.py test on (`start=0.9`), which
  follows file numbers, not objects. Fold 0 only, k unused: their one way to another split,
  `--ds-rotate` (the file list rotated by a fraction before the cut), is swept by no script of
  theirs and is not offered; another fold is a ValueError.
- Test views (inputs.PUBLIC_TEST_CROP): `_get_crop_attrs`' window of 224 px centred on the mean of
  all ground-truth corners (truncated to whole pixels), clamped to the photo, with no rotation and
  zoom 1 (evaluate.py and eval_ggcnn.py without --augment). The training views are honest's:
  `copies` augmented views of each training photo with label-centred crops (KOSMOS-E's recipe, as
  above).
- Detection (public_detect.detect_grasps), their order: the angle 0.5 atan2(sin, cos) is taken
  first and then blurred (sigma 2), the quality blurred (sigma 2), the width x 150 blurred (sigma 1);
  the grasp is peak_local_max(quality, min_distance=20, threshold_abs=0.2, num_peaks=1): the highest
  pixel that is the maximum of its 41 x 41 window, strictly above 0.2 and 20 px or more from every
  edge. None: the view has no grasp (a NaN row) and counts as a failure (`grasps_not_found` in the
  test record and in evaluate's results).
- Metric (scoring.fold_scores.metric_settings): the one grasp keeps its predicted opening w and a
  jaw h = w / 2 (Grasp.as_gr; metrics wh_policy "predicted"), and succeeds when, against some
  ground truth of the view, the angle differs by at most 30 degrees (GraspRectangle.iou returns 0
  beyond pi/6) and the IoU counted over integer pixel centres (skimage's polygon; metrics backend
  "reference") is above 0.25 (calculate_iou_match). Accuracy: the share of test views that succeed.
What stays ours under `public`: corners stay floats (theirs are rounded and truncated); our frame
puts pixel centres at half-integers, so the grasp sits at (column + 0.5, row + 0.5) where theirs sits
at the integer (row, column) of their index frame (a half-pixel shift of labels and grasps alike,
which moves only which pixel centres the IoU counts); a ground truth whose centre leaves the 224
crop is dropped (make_views), theirs stays in the list; equal peaks go to the first in row-major
order (today's skimage's stable sort; older releases may order ties otherwise); GG-CNN crops 300 px, both
networks here take 224; and their train_network.py's validation (the figure in its saved models'
names) scores the SAME dataset object the training reads, with random quarter turns and zooms of
0.5 to 1 on the test views too, where we follow evaluate.py's plain crops.
"""

from kosmos_jax.baselines.ggcnn2 import GGCNN2
from kosmos_jax.baselines.grconvnet import GRConvNet
from kosmos_jax.baselines.layers import MODES, GraspMaps, input_channels
from kosmos_jax.baselines.losses import NETWORK_LOSS, map_losses, per_image
from kosmos_jax.baselines.predict import predict_grasps
from kosmos_jax.baselines.targets import WIDTH_SCALE, grasp_maps

__all__ = ["GGCNN2", "GRConvNet", "GraspMaps", "MODES", "NETWORK_LOSS", "WIDTH_SCALE", "grasp_maps",
           "input_channels", "map_losses", "per_image", "predict_grasps"]
