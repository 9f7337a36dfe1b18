"""bench/exrimage.py — the benches' one reader of the renderer's EXR output (OpenImageIO):
read_rgb(path) is the image's first three channels as float64, H x W x 3."""
import numpy as np
import OpenImageIO as oiio


def read_rgb(path):
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise SystemExit(f"bench: cannot read {path}: {oiio.geterror()}")
    try:
        px = inp.read_image(oiio.FLOAT)
    finally:
        inp.close()
    return np.asarray(px, dtype=np.float64)[..., :3]
