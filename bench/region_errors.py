"""bench/region_errors.py — an image's error inside and outside a region of the image, and the
least error the whole image could have if the region's pixels were exact.

  /usr/bin/python3 bench/region_errors.py MASK.exr REF.exr IMG.exr[,IMG.exr...] ...

MASK: any image whose non-black pixels are the region (bench/sss_hybrid_map.c writes the pixels
whose primary hit is translucent in colour, the others black). REF: the reference (one EXR, or
halves joined by commas, averaged). Each further argument is a group of images (commas), scored
one by one and the figures averaged over the group (seeds).

MAPE and relMSE are means of per-pixel terms (errors.pixel_terms, the same as errors.metrics and
`restir compare`: MAPE's denominator takes 1 % of the whole reference's mean; pixels with a
non-finite channel are left out), so the whole image's figure is the pixel-weighted mix of the two
parts' and "if exact inside" is the outside's sum over all pixels: the floor a method that
improves only the region can reach. RMSE is the square root of such a mean."""
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import errors  # noqa: E402
from exrimage import read_rgb  # noqa: E402


def region_figures(img, ref, mask):
    """Each metric over the whole image, inside the mask, outside it, and over the whole image
    were the inside exact (the outside's terms over all scored pixels), from errors.pixel_terms."""
    t = errors.pixel_terms(img, ref)
    if t is None:
        raise SystemExit("region_errors: no pixel has finite values in both the image and the reference")
    ok = t["ok"]
    inside, outside = ok & mask, ok & ~mask
    out = {}
    for key, name, f in (("mape", "mape", float), ("relmse", "relmse", float), ("sq", "rmse", math.sqrt)):
        v = t[key]
        out[name] = {"all": f(v[ok].mean()), "inside": f(v[inside].mean()) if inside.any() else math.nan,
                     "outside": f(v[outside].mean()) if outside.any() else math.nan,
                     "if_exact_inside": f(v[outside].sum() / ok.sum())}
    return out


def main(argv):
    if len(argv) < 3:
        raise SystemExit(__doc__)
    mask = read_rgb(argv[0])[..., :3].sum(-1) > 0
    ref = np.mean([read_rgb(p)[..., :3] for p in argv[1].split(",")], axis=0)
    if ref.shape[:2] != mask.shape:
        raise SystemExit(f"region_errors: the mask is {mask.shape[1]}x{mask.shape[0]}, the reference "
                         f"{ref.shape[1]}x{ref.shape[0]}")
    print(f"region: {int(mask.sum())} of {mask.size} pixels ({100 * mask.mean():.1f} %)")
    print("| images | metric | whole image | inside | outside | whole image if exact inside |")
    print("|---|---|---|---|---|---|")
    for group in argv[2:]:
        paths = group.split(",")
        figs = [region_figures(read_rgb(p), ref, mask) for p in paths]
        for name in ("mape", "relmse", "rmse"):
            row = [np.mean([f[name][k] for f in figs]) for k in ("all", "inside", "outside", "if_exact_inside")]
            label = Path(paths[0]).name + (f" (+{len(paths) - 1})" if len(paths) > 1 else "")
            print(f"| {label} | {name} | " + " | ".join(f"{x:.4g}" for x in row) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
