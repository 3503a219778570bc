"""Meshes beside the photos: held-out views of a NeuS-layout capture, each mesh shaded from that camera.

    python benchmarks/capture_pictures.py --capture DTU_SCAN65 --views 12 31 \\
        --mesh "masks=OUT/masks-ds4.obj" --mesh "photos=OUT/ds4.obj" \\
        --mesh "photos + consistency=OUT2/ds4-photo-consistency-1.obj" --out docs/photo_consistency_dtu.png

Rows are the views (indices into the capture, e.g. the ones `captures.py` held out); the first
column is the photo, then one column per mesh: the mesh shaded under a headlight in that
camera (`jaxgenus.render`, channel "shaded"), blended over the photo's masked-out background
so that the silhouettes and the inner shape can be compared. Images at 1/`--downsample`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from _report import pyplot

import jaxgenus as jg


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", type=Path, required=True)
    ap.add_argument("--views", type=int, nargs="+", required=True)
    ap.add_argument("--mesh", action="append", required=True, metavar="LABEL=PATH")
    ap.add_argument("--downsample", type=int, default=4)
    ap.add_argument("--out", type=Path, default=Path("capture_pictures.png"))
    ap.add_argument("--dpi", type=int, default=60)
    args = ap.parse_args()
    files = sorted(p for p in (args.capture / "image").iterdir() if p.suffix.lower() in (".png", ".jpg"))
    masks = sorted(p for p in (args.capture / "mask").iterdir() if p.suffix.lower() in (".png", ".jpg"))
    loaded = jg.load_images([str(files[i]) for i in args.views], masks=[str(masks[i]) for i in args.views])
    h, w = loaded.images.shape[1:3]
    cams, _ = jg.load_cameras(args.capture / "cameras_sphere.npz", image_size=(h, w))
    f = args.downsample
    cams = jg.optim.scaled_cameras(cams[np.array(args.views)], f)
    photos = loaded.images[:, : cams.height * f, : cams.width * f]
    photos = photos.reshape(len(args.views), cams.height, f, cams.width, f, 4).mean(axis=(2, 4))
    meshes = [(label, jg.load_mesh(path)) for label, path in (m.split("=", 1) for m in args.mesh)]
    plt = pyplot()
    if plt is None:
        raise SystemExit("matplotlib is needed for the pictures")
    cols = 1 + len(meshes)
    fig, ax = plt.subplots(len(args.views), cols, figsize=(3.2 * cols, 2.5 * len(args.views)), squeeze=False)
    for r, view in enumerate(args.views):
        ax[r, 0].imshow(np.clip(photos[r, ..., :3], 0, 1))
        ax[r, 0].set_title(f"photo {view} (held out)" if r == 0 else f"photo {view}", fontsize=9)
        for c, (label, mesh) in enumerate(meshes, start=1):
            img = np.asarray(jg.render(mesh, cams[r:r + 1], channels=("alpha", "shaded")))[0]
            a = img[..., :1]
            grey = np.repeat(img[..., 1:2], 3, axis=-1)
            back = 0.35 * photos[r, ..., :3]
            ax[r, c].imshow(np.clip(a * grey + (1 - a) * back, 0, 1))
            if r == 0:
                ax[r, c].set_title(label, fontsize=9)
    for a in ax.ravel():
        a.set_axis_off()
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=args.dpi)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
