#!/usr/bin/env python3
"""Compute per-frame open-vocabulary features for ``latentam convert --features DIR``.

This is an optional helper for users who have CLIP (``open_clip_torch``) and,
for the default mode, Segment Anything (``segment_anything``) installed,
together with ``torch``, ``numpy``, ``Pillow`` and ``safetensors``.  Nothing in
the engine's tests runs it.  The heavy packages are imported only when a
frame is processed, so ``--help`` works without them.

Output layout
=============

``OUT_DIR`` receives one file per colour image, named after the image file's
stem with the ``.safetensors`` extension::

    IMAGES_DIR/frame-000000.color.jpg  ->  OUT_DIR/frame-000000.color.safetensors

(The converter also accepts the stem without its ``.color`` suffix, e.g.
``frame-000000.safetensors``; this tool always keeps the full stem.)

Every file is a standard safetensors file (little-endian tensors) in one of
two formats, told apart by the ``format`` entry of its metadata.

Region features (the default)
-----------------------------

``labels``
    dtype U16, shape ``[H, W]`` with H × W the colour image's size: the region
    index of each pixel, row-major; ``65535`` marks pixels in no region.
``features``
    dtype F16, shape ``[N, D]``: row ``i`` is the embedding of region ``i``
    (``0 <= i < N``, ``N <= --max-regions``), L2-normalised, ``D`` being the
    CLIP model's embedding size.  Every index in ``0..N`` occurs in
    ``labels`` at least once.
metadata
    ``{"model": "<clip model>+sam-<variant>", "format": "latentam-mask-features-1"}``,
    e.g. ``"ViT-B-16+sam-vit_h"``.

Regions come from SAM's automatic mask generator.  Masks smaller than
``--min-mask-area`` pixels are discarded and the ``--max-regions`` largest of
the rest are kept, indexed from the largest (0) to the smallest.  Labels are
painted largest first, so where masks overlap a pixel belongs to the smallest
mask covering it; a mask left with no visible pixel is dropped and the
indices are compacted.  A region's embedding is CLIP's image embedding of its
whole mask: the mask's bounding box is cropped from the image, the pixels
outside the mask are replaced with CLIP's mean colour, the crop is padded to
a square with the same colour, and the result is encoded with CLIP's image
encoder and L2-normalised.

Feature grid (``--grid R C``)
-----------------------------

``grid``
    dtype F16, shape ``[R, C, D]``: the L2-normalised CLIP embedding of each
    cell.  The image is cut into R rows and C columns of cells; cell ``(r, c)``
    spans pixel rows ``floor(r * H / R) .. floor((r + 1) * H / R)`` and pixel
    columns ``floor(c * W / C) .. floor((c + 1) * W / C)`` (end exclusive),
    padded to a square with CLIP's mean colour before encoding.
metadata
    ``{"model": "<clip model>", "format": "latentam-feature-grid-1"}``.

SAM is not loaded in grid mode.  The ``model`` string must match the one used
for the text embeddings of the query vocabulary: maps refuse to mix models.

Example::

    python3 tools/python/extract_features.py scene/seq-01 features/seq-01 \\
        --glob '*.color.png' --sam-checkpoint sam_vit_h_4b8939.pth
    latentam convert ... --features features/seq-01
"""

import argparse
import sys
from pathlib import Path

NO_REGION = 65535
MASK_FORMAT = "latentam-mask-features-1"
GRID_FORMAT = "latentam-feature-grid-1"
SAM_VARIANTS = ("vit_h", "vit_l", "vit_b")
# CLIP's normalisation mean as 8-bit RGB: filled pixels normalise to zero.
CLIP_MEAN_RGB = (123, 117, 104)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(
        description=(
            "Write one .safetensors feature file per colour image for "
            "'latentam convert --features OUT_DIR'. By default each file holds a SAM "
            "region label image ('labels', U16 [H, W], 65535 = no region) and one "
            "L2-normalised CLIP embedding per region ('features', F16 [N, D]); with "
            "--grid it holds a grid of cell embeddings ('grid', F16 [R, C, D]). "
            "See the module docstring for the exact layout."
        ),
    )
    parser.add_argument("images_dir", metavar="IMAGES_DIR", type=Path, help="directory of colour images")
    parser.add_argument(
        "out_dir",
        metavar="OUT_DIR",
        type=Path,
        help="directory for the feature files (created if missing); each is named "
        "after its image's stem, e.g. frame-000000.color.jpg -> frame-000000.color.safetensors",
    )
    parser.add_argument(
        "--glob",
        default="*.jpg",
        help="pattern selecting the colour images inside IMAGES_DIR, not recursive "
        "(default: %(default)s; e.g. '*.color.png' for 7-Scenes-style directories)",
    )
    parser.add_argument("--clip-model", default="ViT-B-16", help="open_clip model name, also written as the 'model' metadata (default: %(default)s)")
    parser.add_argument("--clip-pretrained", default="laion2b_s34b_b88k", help="open_clip pretrained weights tag (default: %(default)s)")
    parser.add_argument(
        "--sam-checkpoint",
        type=Path,
        default=None,
        help="path of the Segment Anything checkpoint (.pth); required unless --grid is given",
    )
    parser.add_argument(
        "--sam-variant",
        choices=SAM_VARIANTS,
        default="vit_h",
        help="SAM backbone matching the checkpoint; recorded in the 'model' metadata as '+sam-<variant>' (default: %(default)s)",
    )
    parser.add_argument(
        "--grid",
        nargs=2,
        type=int,
        metavar=("R", "C"),
        default=None,
        help="write a feature grid of R rows x C columns of CLIP cell embeddings instead of SAM regions",
    )
    parser.add_argument(
        "--min-mask-area",
        type=int,
        default=100,
        help="discard SAM masks covering fewer pixels than this (default: %(default)s)",
    )
    parser.add_argument(
        "--max-regions",
        type=int,
        default=200,
        help="keep at most this many regions per image (the largest ones); below 65535 (default: %(default)s)",
    )
    parser.add_argument(
        "--device",
        choices=("auto", "cuda", "cpu"),
        default="auto",
        help="torch device for CLIP and SAM; 'auto' picks cuda when torch sees a GPU, else cpu (default: %(default)s)",
    )
    parser.add_argument("--batch-size", type=int, default=32, help="crops encoded by CLIP at once (default: %(default)s)")
    parser.add_argument(
        "--skip-existing",
        action="store_true",
        help="leave images whose feature file already exists untouched",
    )
    args = parser.parse_args(argv)

    if args.grid is None and args.sam_checkpoint is None:
        parser.error("--sam-checkpoint is required for region features (or give --grid R C)")
    if args.grid is not None and (args.grid[0] < 1 or args.grid[1] < 1):
        parser.error("--grid needs positive R and C")
    if not 1 <= args.max_regions < NO_REGION:
        parser.error(f"--max-regions must be between 1 and {NO_REGION - 1}")
    if args.min_mask_area < 0:
        parser.error("--min-mask-area must not be negative")
    if args.batch_size < 1:
        parser.error("--batch-size must be positive")
    return args


# Python module -> the pip package that provides it.
REQUIRED_MODULES = {
    "numpy": "numpy",
    "PIL": "Pillow",
    "safetensors": "safetensors",
    "torch": "torch",
    "open_clip": "open_clip_torch",
}
SAM_MODULE = ("segment_anything", "segment-anything (from github.com/facebookresearch/segment-anything)")


def missing_packages(need_sam):
    """The pip packages whose modules cannot be imported."""
    import importlib.util

    modules = dict(REQUIRED_MODULES)
    if need_sam:
        modules[SAM_MODULE[0]] = SAM_MODULE[1]
    return [pip for module, pip in modules.items() if importlib.util.find_spec(module) is None]


def output_path(image_path, out_dir):
    """frame-000000.color.jpg -> OUT_DIR/frame-000000.color.safetensors"""
    return out_dir / (image_path.stem + ".safetensors")


def pick_device(requested):
    import torch

    if requested == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if requested == "cuda" and not torch.cuda.is_available():
        raise SystemExit("extract_features: --device cuda given but torch sees no CUDA device")
    return requested


class ClipEncoder:
    """CLIP's image encoder applied to lists of RGB crops."""

    def __init__(self, model_name, pretrained, device, batch_size):
        import open_clip
        import torch

        self.torch = torch
        self.device = device
        self.batch_size = batch_size
        self.model, _, self.preprocess = open_clip.create_model_and_transforms(
            model_name, pretrained=pretrained, device=device
        )
        self.model.eval()

    def encode(self, crops):
        """L2-normalised embeddings of `crops` (HxWx3 uint8 arrays) as float16 [N, D]."""
        import numpy as np
        from PIL import Image

        torch = self.torch
        rows = []
        with torch.no_grad():
            for start in range(0, len(crops), self.batch_size):
                batch = torch.stack(
                    [self.preprocess(Image.fromarray(square(c))) for c in crops[start : start + self.batch_size]]
                ).to(self.device)
                emb = self.model.encode_image(batch).float()
                emb = emb / emb.norm(dim=-1, keepdim=True).clamp_min(1e-12)
                rows.append(emb.cpu().numpy())
        return np.concatenate(rows, axis=0).astype(np.float16)


def square(crop):
    """Pads an HxWx3 crop to a centred square filled with CLIP's mean colour."""
    import numpy as np

    h, w = crop.shape[:2]
    side = max(h, w)
    if h == w:
        return crop
    out = np.empty((side, side, 3), dtype=np.uint8)
    out[...] = CLIP_MEAN_RGB
    top, left = (side - h) // 2, (side - w) // 2
    out[top : top + h, left : left + w] = crop
    return out


def region_features(image, generator, clip, min_area, max_regions):
    """(labels U16 [H, W], features F16 [N, D]) for one RGB image."""
    import numpy as np

    masks = [m["segmentation"].astype(bool) for m in generator.generate(image)]
    masks = [m for m in masks if int(m.sum()) >= max(min_area, 1)]
    masks.sort(key=lambda m: int(m.sum()), reverse=True)
    masks = masks[:max_regions]

    h, w = image.shape[:2]
    painted = np.full((h, w), -1, dtype=np.int64)
    for index, mask in enumerate(masks):  # largest first: smaller masks end on top
        painted[mask] = index
    visible = [i for i in range(len(masks)) if (painted == i).any()]

    labels = np.full((h, w), NO_REGION, dtype=np.uint16)
    crops = []
    for new_index, old_index in enumerate(visible):
        labels[painted == old_index] = new_index
        mask = masks[old_index]
        ys, xs = np.nonzero(mask)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        crop = image[y0:y1, x0:x1].copy()
        crop[~mask[y0:y1, x0:x1]] = CLIP_MEAN_RGB
        crops.append(crop)

    if crops:
        features = clip.encode(crops)
    else:
        dim = int(clip.encode([np.zeros((8, 8, 3), dtype=np.uint8)]).shape[1])
        features = np.zeros((0, dim), dtype=np.float16)
    return labels, features


def grid_features(image, clip, rows, cols):
    """F16 [rows, cols, D] cell embeddings of one RGB image."""
    h, w = image.shape[:2]
    if rows > h or cols > w:
        raise SystemExit(f"extract_features: --grid {rows} {cols} is finer than the {w}x{h} image")
    crops = []
    for r in range(rows):
        y0, y1 = r * h // rows, (r + 1) * h // rows
        for c in range(cols):
            x0, x1 = c * w // cols, (c + 1) * w // cols
            crops.append(image[y0:y1, x0:x1])
    features = clip.encode(crops)
    return features.reshape(rows, cols, features.shape[1])


def main(argv=None):
    args = parse_args(argv)
    images = sorted(p for p in args.images_dir.glob(args.glob) if p.is_file())
    if not images:
        print(f"extract_features: no file in {args.images_dir} matches {args.glob!r}", file=sys.stderr)
        return 1
    missing = missing_packages(need_sam=args.grid is None)
    if missing:
        print("extract_features: missing Python packages: " + ", ".join(missing), file=sys.stderr)
        return 1
    args.out_dir.mkdir(parents=True, exist_ok=True)

    import numpy as np
    from PIL import Image
    from safetensors.numpy import save_file

    device = pick_device(args.device)
    clip = ClipEncoder(args.clip_model, args.clip_pretrained, device, args.batch_size)
    generator = None
    if args.grid is None:
        from segment_anything import SamAutomaticMaskGenerator, sam_model_registry

        sam = sam_model_registry[args.sam_variant](checkpoint=str(args.sam_checkpoint))
        sam.to(device)
        generator = SamAutomaticMaskGenerator(sam)
        metadata = {"model": f"{args.clip_model}+sam-{args.sam_variant}", "format": MASK_FORMAT}
    else:
        metadata = {"model": args.clip_model, "format": GRID_FORMAT}

    for number, path in enumerate(images, start=1):
        out = output_path(path, args.out_dir)
        if args.skip_existing and out.exists():
            continue
        image = np.asarray(Image.open(path).convert("RGB"))
        if generator is not None:
            labels, features = region_features(image, generator, clip, args.min_mask_area, args.max_regions)
            tensors = {"labels": np.ascontiguousarray(labels), "features": np.ascontiguousarray(features)}
            summary = f"{features.shape[0]} regions"
        else:
            grid = grid_features(image, clip, args.grid[0], args.grid[1])
            tensors = {"grid": np.ascontiguousarray(grid)}
            summary = f"{args.grid[0]}x{args.grid[1]} grid"
        save_file(tensors, str(out), metadata=metadata)
        print(f"[{number}/{len(images)}] {path.name} -> {out.name} ({summary})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
