"""bench/exrimage.py — the benches' one reader of the renderer's EXR output (OpenImageIO):
read_rgb(path) is the image's first three channels as float64, H x W x 3; write_rgb(path, img)
writes such an image as a float RGB EXR."""
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


def write_rgb(path, img):
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(img.shape[1], img.shape[0], 3, oiio.FLOAT)):
        raise SystemExit(f"bench: cannot write {path}: {oiio.geterror()}")
    ok = out.write_image(np.ascontiguousarray(img, dtype=np.float32))
    ok = out.close() and ok
    if not ok:
        raise SystemExit(f"bench: cannot write {path}: {oiio.geterror()}")
