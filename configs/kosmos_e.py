"""KOSMOS-E training: one config, variants after the colon.

    python -m kosmos_jax.train --config=configs/kosmos_e.py:tiny --workdir=runs/tiny
    launch/local.sh train configs/kosmos_e.py:demo --workdir=runs/demo --config.train.steps=500
    PROCESSES=2 FAKE_DEVICES=2 launch/local.sh train configs/kosmos_e.py:tiny --workdir=runs/mp
    python -m kosmos_jax.train.compile --config=configs/kosmos_e.py:paper --topology=v5e:2x4

Variants:
  tiny   transformers' test-sized model, a small synthetic set, seconds a step (the tests use it)
  demo   the from-scratch recipe of the studies: a model small enough to learn something in minutes on 2
         cores, 300 photos of 16 augmented views each
  demo_photos  demo on 1,200 photos of 4 views each, the same number of views
         (results/scale_study: 42.49 on validation against demo's 36.63, same steps)
  demo_photos_finetune  demo_photos from a start (--config.init_from, e.g. the committed
         results/pretrain/demo_photos1200) at a lower peak learning rate, chosen on validation
         (results/pretrain/README.md, "The fine-tune's learning rate"); the experiments' pretrained arms
  demo_grounded  demo_photos_finetune from a grounding start (the committed results/pretrain/grounding14000:
         its connector reads the instruction) on NON and the six multi-object kinds on mosaics for 400 steps
         (results/pretrain/README.md, "The grounding start shipped"; chosen there for
         results/pretrain/grounding6000); the experiments' grounded arms, and make demo until 2026-12-06
         for 800 steps (results/finetune_length)
  demo_grounded224  demo_grounded on a 16 x 16 grid of patches (224 px views) from a
         start pretrained on that grid (the committed results/pretrain/grounding21200), 400 steps at half its
         peak learning rate
         (results/finer_grid/README.md)
  demo_grounded224_consensus  what `make demo` trains: demo_grounded224 with the consensus grasp as each view's
         target (text/target_rows.py; results/finer_grid/README.md)
  demo_gpu  demo on four times the photos for three times the steps: minutes on a GPU, about an hour on 2
         cores (53 minutes, results/pretrain/README.md)
         (results/scale_study: 48.35 on validation against 33.33 on demo's 300 photos, same steps)
  demo_finetune  demo's data and schedule from a pretraining run (configs/pretrain.py:demo):
         give --config.init_from=ITS_WORKDIR (its tokenizer and model come with it)
  demo_kosmos2  the same model with KOSMOS-2's connector, digits and label-centred crops (the
         experiments' cpu arms; its answers ignore the photo)
  small  the `small` model of kosmos_jax.models.config
  paper  the KOSMOS-2 size initialised from a KOSMOS-2 folder (config.init_from), the
         paper's optimiser and its data build (Cornell, individual outputs, angle code, XYA)

config.data.build holds the settings of `python -m kosmos_jax.dataset.build` (kosmos_jax.dataset.build
.BuildConfig, less source and out). config.data.source is "synthetic" (scenes the project makes:
config.data.synthetic_photos, config.data.synthetic_seed), "cornell" (../shared/data/cornell) or a
Cornell-format folder. The trainer builds the dataset under config.data.root on first use and
reuses an identical build afterwards; config.data.dir names an already built dataset folder instead.
"""

import dataclasses

import ml_collections
from ml_collections.config_dict import placeholder

from kosmos_jax.models.config import TextConfig, VisionConfig

VARIANTS = ("tiny", "demo", "demo_photos", "demo_photos_finetune", "demo_grounded", "demo_grounded224", "demo_grounded224_consensus", "demo_gpu", "demo_finetune", "demo_kosmos2", "small", "paper")


FINETUNE_PEAK_LR = 3e-4  # demo_photos_finetune's: 49.82 on validation against 47.99 at demo's 1e-3


def data_config(**changes) -> ml_collections.ConfigDict:
    data = ml_collections.ConfigDict()
    data.dir = ""  # an already built dataset folder (holding build_stats.json); "" = build it
    data.root = "datasets"  # where builds and synthetic scenes are written (relative to the working directory)
    data.source = "synthetic"
    data.synthetic_photos = 40
    data.synthetic_seed = 0
    # photos > 0: training batches from scenes made on the fly, chunks of that many photos of seeds
    # seed, seed + 1, ... (train/scene_stream.py); the built dataset then gives the tokenizer, validation and test.
    # kinds: the stream's instruction kinds as data.build.kinds takes them ("non,multi"); "" = the build's;
    # examples > 0: keep that many of a chunk's examples, drawn at random (more scenes for the same steps)
    # targets "best": each scene keeps only its expected best grasp (sources/synthetic/best_grasps.py); "": its draw
    data.stream = ml_collections.ConfigDict(dict(photos=0, seed=10_000, kinds="", examples=0, targets=""))
    # "non=3": each training example of that kind drawn 3 times an epoch, the other kinds' once (the mix the
    # trainer sees, from the same build); "" = every example once. Not with the scene stream.
    data.kind_repeats = ""
    data.build = ml_collections.ConfigDict(dict(
        protocol="honest", split="image", fold=0, folds=5, annotations=placeholder(str), augmentations=4,
        recipe="random", kinds="non", seed=0, fold_seed=placeholder(int), train_crop=placeholder(str),
        test_crop=placeholder(str), representation="xya", angle_code=True, individual=True, loss_on="target",
        target_grasp="random", numbers="digits", max_length=128, overflow="error", tokenizer=placeholder(str),
        tokenizer_scheme="fairseq", text_pieces=1000, unambiguous=True, batch_size=8,
        validation_fraction=0.0,  # > 0: that share of the training photos held out as split "validation" (honest)
    ))
    data.update(changes.pop("top", {}))
    data.build.update(changes)
    return data


def size_changes(fields_of, **values) -> ml_collections.ConfigDict:
    """Every field of a model dataclass, None (= the size's own value) unless given."""
    types = {"int": int, "float": float, "bool": bool, "str": str}
    changes = ml_collections.ConfigDict({f.name: placeholder(types[f.type]) for f in dataclasses.fields(fields_of)})
    changes.update(values)
    return changes


def model_config(size: str, vision: dict | None = None, text: dict | None = None, **changes) -> ml_collections.ConfigDict:
    model = ml_collections.ConfigDict()
    model.size = size  # a size of kosmos_jax.models.config: tiny, small, kosmos2
    model.vision = size_changes(VisionConfig, **(vision or {}))  # e.g. --config.model.vision.image_size=112
    model.text = size_changes(TextConfig, **(text or {}))  # vocab_size: None = the tokenizer's
    model.latent_query_num = 64  # must equal the prompt's 64 image slots
    model.compute_dtype = "float32"
    model.remat = False
    model.dropout_mask_bits = 32  # 16 or 8: the dropout masks from fewer random bits (the rate rounded)
    model.remat_policy = "full"  # under remat: "dots" keeps the dense layers' outputs (more memory, less recomputed)
    model.scan_layers = False
    model.attention = "einsum"  # or "fused": jax.nn.dot_product_attention (cuDNN's flash kernel on a GPU)
    model.magneto_init = True
    model.connector_dense_std = placeholder(float)  # None: KOSMOS-2 init (0.02); from scratch, try 1.0
    model.connector_grid_code = 0.0  # 0: KOSMOS-2's connector; > 0: centred tokens + a grid-cell code (from scratch)
    model.connector_instruction = False  # True: the latent queries also read the prompt's words (from scratch)
    model.value_token_code = 0.0  # > 0: value tokens' embeddings start near each other's for near values (from scratch)
    model.angle_code_bins = 0.0  # > 0: the angle tokens' start codes are about this many bins alike; 0: 2 to 3 bins
    model.update(changes)
    return model


def demo_model(**changes) -> ml_collections.ConfigDict:
    """The demo's small model: 4-layer vision tower (112 px, 14 px patches) and decoder, width 128."""
    return model_config("small", vision=dict(hidden_size=128, intermediate_size=512, num_hidden_layers=4,
                                             num_attention_heads=4, image_size=112, patch_size=14),
                        text=dict(embed_dim=128, ffn_dim=512, layers=4, attention_heads=4), **changes)


def optimizer_config(**changes) -> ml_collections.ConfigDict:
    optimizer = ml_collections.ConfigDict()
    optimizer.name = "adamw"
    optimizer.peak_lr = 1e-3
    optimizer.end_lr = 0.0
    optimizer.warmup_steps = 20
    optimizer.decay_steps = 0  # 0: linear decay reaches end_lr at train.steps
    optimizer.b1 = 0.9
    optimizer.b2 = 0.98
    optimizer.eps = 1e-6
    optimizer.weight_decay = 0.01
    optimizer.clip_norm = 1.0  # global-norm clipping; None turns it off
    optimizer.decay_mask = "logical"  # no decay on parameters whose logical axes are "norm" (LayerNorm), biases, embeddings
    optimizer.update(changes)
    return optimizer


def train_config(**changes) -> ml_collections.ConfigDict:
    train = ml_collections.ConfigDict()
    train.steps = 30
    train.batch_size = 8  # global, over all processes and devices
    train.microbatches = 1
    train.log_every = 1
    train.eval_every = 0  # 0: only at the end
    train.eval_batches = 4  # test batches per evaluation (0: the whole test split)
    train.grasp_eval_every = 0  # grasp accuracy of decoded test answers every N steps (0: only at the end)
    # decode the test answers at the end too (the last line's grasp_accuracy); a caller that scores the finished
    # run with the evaluate command's code, which decodes them again, turns it off (make demo)
    train.grasp_eval_at_end = True
    train.pointing_loss = 0.0  # weight of the connector's pointing loss (kosmos_jax.train.loss.pointing_sum); 0: none
    train.angle_smoothing = 0.0  # > 0: circular smooth labels on angle tokens, this many bins wide (train.loss); 0: none
    # "cell": the pointing loss asks for the grasp's patch; "bilinear": the four patches around its centre, each
    # in proportion to its nearness, so the pointed slots carry the centre's grid code between cells;
    # "identity": latent query q looks at patch q, whatever the grasp (the slots become the patches)
    train.pointing_target = "cell"
    train.pointing_queries = 0  # > 0: the pointing loss points only the first this many latent queries; 0: all
    train.patch_angle_loss = 0.0  # weight of the loss that asks the grasp's patch token for its angle bin (train.loss); 0: none
    train.tower_angle_loss = 0.0  # weight of the loss that reads the tower's grasp patch as (cos, sin) of 2*angle (train.loss); 0: none
    train.slot_angle_loss = 0.0  # weight of the same read of every image slot the decoder gets (train.loss); 0: none
    # weights of the losses that ask the tower's grasp patch and every slot where in that patch the centre lies
    train.tower_offset_loss = 0.0
    train.slot_offset_loss = 0.0
    # weight of the loss that asks the decoder, at each answer token, which slot holds the target grasp's
    # patch (train.loss.answer_pointing_sum; needs pointing_target "identity"); 0: none
    train.answer_pointing_loss = 0.0
    # weight of the contrastive loss matching each instruction's words with the tower's feature at its
    # grasp's patch among the batch's (train.phrase_patch.phrase_patch_sum); 0: none
    train.phrase_patch_loss = 0.0
    # weights of the losses that read the tower's grasp patch as its object's category and as its main
    # colour (train.tower_labels; the labels come from the scene stream: needs config.data.stream); 0: none
    train.tower_category_loss = 0.0
    train.tower_colour_loss = 0.0
    train.checkpoint_every = 10
    train.keep_checkpoints = 3
    train.seed = 0
    train.update(changes)
    return train


def mesh_config(data: int = -1, fsdp: int = 1, tensor: int = 1) -> ml_collections.ConfigDict:
    return ml_collections.ConfigDict(dict(data=data, fsdp=fsdp, tensor=tensor))  # -1 = all devices left


def get_config(arg: str | None = None) -> ml_collections.ConfigDict:
    variant = arg or "tiny"
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r} of configs/kosmos_e.py; expected one of {VARIANTS}")
    config = ml_collections.ConfigDict()
    config.variant = variant
    # a KOSMOS-2 folder (config.json + model.safetensors, read by weights.load_pretrained), or a run's workdir
    # (train/run_start.py: its checkpoint init_step's parameters, -1 = the newest, and its tokenizer)
    config.init_from = ""
    config.init_step = -1
    # True: a start whose vision tower has another image_size (the same patch_size) is taken with its position
    # embeddings resampled to this config's grid of patches (train/run_start.py)
    config.init_resample_positions = False
    config.require_init = False
    config.mesh = mesh_config()
    # how the answers are read (kosmos_jax.models.value_decoding): a coordinate value token as the local
    # mean of the model's distribution within this many values of its mode; 0: greedy. 32 was chosen on
    # validation (results/location_study); it acts only on vocabularies with value tokens (numbers="values").
    # An angle token likewise, around the circle within this many of its 256 bins (0: the mode); 32 was
    # chosen on validation: the same accuracy as the mode, answers spread over the bins as the targets
    # are (results/pretrain/README.md, "Reading the angle")
    config.decode = ml_collections.ConfigDict(dict(value_window=32, angle_window=32))
    if variant == "tiny":
        config.data = data_config(top=dict(synthetic_photos=16), augmentations=2, max_length=96, text_pieces=300)
        config.model = model_config("tiny")
        config.optimizer = optimizer_config(peak_lr=3e-3, warmup_steps=5)
        config.train = train_config(steps=30, batch_size=8, checkpoint_every=10)
    elif variant == "demo":
        # From scratch in minutes (results/demo/diagnosis.txt, sections 5 to 7): training crops on the photo
        # centre as the honest test views are; one token a value, whose embeddings start smooth in the value;
        # a connector that is taught to point at the grasp's patch and carries that patch's grid cell;
        # the tower's grasp patch and every slot the decoder reads also asked for the angle, without which
        # the decoder answers one angle for every photo (results/angle_study: 38.89 against 24.07 on
        # validation, on seeds 0 and 1 alike)
        config.data = data_config(top=dict(synthetic_photos=300), augmentations=16, train_crop="image_centre",
                                  numbers="values", max_length=88)
        config.model = demo_model(connector_dense_std=1.0, connector_grid_code=3.0, value_token_code=2.0)
        config.optimizer = optimizer_config(peak_lr=1e-3, warmup_steps=100)
        # 800 steps: about 10 minutes of `make demo`'s 15 on 2 quiet cores (0.7 s a step)
        config.train = train_config(steps=800, batch_size=32, log_every=10, eval_every=400, checkpoint_every=100,
                                    pointing_loss=1.0, tower_angle_loss=4.0, slot_angle_loss=1.0)
    elif variant == "demo_photos":
        config = get_config("demo")
        config.variant = variant
        config.data.synthetic_photos = 1200
        config.data.build.augmentations = 4
    elif variant == "demo_photos_finetune":
        config = get_config("demo_photos")
        config.variant = variant
        config.model.value_token_code = 0.0  # the start's embeddings are loaded, not made afresh
        config.optimizer.peak_lr = FINETUNE_PEAK_LR
        config.require_init = True
    elif variant == "demo_grounded":
        config = get_config("demo_photos_finetune")
        config.variant = variant
        # the grounding start's connector reads the prompt's words; mosaic instructions run to 120 tokens
        config.model.connector_instruction = True
        config.data.build.update(kinds="non,multi", max_length=128)
        # 400 steps: 20.37 on validation mosaics against 20.99 at 800, at half the training time
        config.train.update(steps=400, eval_every=400)
    elif variant == "demo_grounded224":
        config = get_config("demo_grounded")
        config.variant = variant
        # the 8 x 8 grid's cells are 28 px of the view, a mosaic photo's quadrant four of them: on a 16 x 16 grid
        # (from grounding16400, at 3e-4) the validation mosaics read 33.33 against 21.25 for make demo's 800 steps
        # at 112 px, single photos 60.40 against 59.50 (two seeds; results/finer_grid/README.md)
        config.model.vision.image_size = 224
        # half demo_grounded's peak rate: from grounding21200, 61.90 on validation single photos against 58.79 at
        # 3e-4 and 39.53 on mosaics against 39.38 (two seeds; results/finer_grid/README.md, 2026-12-07)
        config.optimizer.peak_lr = FINETUNE_PEAK_LR / 2
    elif variant == "demo_grounded224_consensus":
        config = get_config("demo_grounded224")
        config.variant = variant
        # one target where the annotation's grasps crowd: 64.35 on validation single photos against 61.90 for a
        # grasp drawn at random, mosaics 38.97 against 39.34 (three seeds; results/finer_grid/README.md, 2026-12-07)
        config.data.build.target_grasp = "consensus"
    elif variant == "demo_gpu":
        config = get_config("demo")
        config.variant = variant
        config.data.synthetic_photos = 1200
        config.train.update(steps=2400, eval_every=800, checkpoint_every=400)
    elif variant == "demo_finetune":
        demo = get_config("demo")
        config.data, config.optimizer, config.train = demo.data, demo.optimizer, demo.train
        config.model = demo_model(connector_dense_std=1.0, connector_grid_code=3.0)  # embeddings: the run's
        config.require_init = True
    elif variant == "demo_kosmos2":
        # The demo model with KOSMOS-2's connector and init, digit numbers and label-centred training crops:
        # what `make demo` trained before 2026-11-25 and what the experiments' cpu arms were run with. Its
        # answers do not depend on the photo (results/demo/diagnosis.txt, section 1).
        config.data = data_config(top=dict(synthetic_photos=300), augmentations=16)
        config.model = demo_model()
        config.optimizer = optimizer_config(peak_lr=1e-3, warmup_steps=100)
        config.train = train_config(steps=400, batch_size=32, log_every=10, eval_every=200, checkpoint_every=100)
    elif variant == "small":
        config.data = data_config(top=dict(synthetic_photos=300), augmentations=16)
        config.model = model_config("small")
        config.optimizer = optimizer_config(peak_lr=5e-4, warmup_steps=100)
        config.train = train_config(steps=3000, batch_size=16, log_every=10, eval_every=500, checkpoint_every=500)
    else:  # paper
        config.data = data_config(top=dict(source="cornell"), augmentations=16, kinds="all", max_length=256,
                                  representation="xya", angle_code=True, individual=True, loss_on="target",
                                  annotations="../shared/data/kosmos-e/instructions-original.json")
        config.model = model_config("kosmos2", compute_dtype="bfloat16")
        config.require_init = True  # training refuses to start from scratch: give --config.init_from
        config.optimizer = optimizer_config(peak_lr=2e-4, end_lr=0.0, warmup_steps=375, decay_steps=30_000, b1=0.9,
                                            b2=0.98, eps=1e-6, weight_decay=0.01, clip_norm=2.0)
        config.train = train_config(steps=30_000, batch_size=64, log_every=50, eval_every=2000, checkpoint_every=1000)
        config.mesh = mesh_config(data=1, fsdp=-1, tensor=1)
    return config
