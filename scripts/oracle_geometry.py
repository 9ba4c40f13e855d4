"""An oracle bound (not part of brfgs, simulated scenes only): ``brfgs train`` on the TRUE geometry.

    python scripts/oracle_geometry.py train SCENE OUT --init-fill mvs --init-fill-points 45000 \
        --lambda-dense-depth 1 --densify-refine-stop 0 --antialias [any other train option]

Takes the same arguments as ``brfgs train``. The only change is where ``--init-fill mvs`` gets its
points and its dense-depth targets: from the simulator's ``truth/depth`` maps of the training views
instead of plane-sweep stereo. Those maps are unprojected to the true surface and thinned to one point
per 5 cm voxel, then to ``--init-fill-points`` (seeded by ``--seed``). The maps are also saved as the
dense-depth targets. ``--densify-refine-stop 0`` keeps the start: no clone, split, prune or opacity
reset. A real flight has no truth depth, so this estimates what exact geometry would give each
appearance head: an upper bound for these settings, not a proof for every schedule. docs/results.md,
Session 50, runs it for BRF-GS and for SH-3 (``--variant sh --from-stage1
OUT/checkpoints/stage1.safetensors``, with the same options).
"""

import zlib  # noqa: F401  (before pycolmap, which breaks zlib when imported first)
import sys

import numpy as np

import brfgs.train.setup as setup
from brfgs.errors import UserError
from brfgs.init.truth import surface_samples
from brfgs.train.dense_depth import FILE, save_dense_depths

VOXEL_M = 0.05


def truth_fill(state, scene, cfg, init, images, folder, log) -> np.ndarray:
    """Points [M, 3] on the true surface of the training views; their truth depth maps become the
    dense-depth targets (stands in for :func:`brfgs.train.setup.dense_fill`)."""
    tr = list(scene.train_indices)
    pts = surface_samples(scene, tr)  # [S, 3] m
    if pts is None:
        raise UserError("the oracle needs the simulator's truth depth maps", file=scene.root / "truth" / "depth",
                        field="depth")
    _, first = np.unique(np.floor(pts / VOXEL_M).astype(np.int64), axis=0, return_index=True)
    pts = pts[np.sort(first)]
    if len(pts) > cfg.init_fill_points:
        keep = np.random.default_rng(cfg.seed).choice(len(pts), cfg.init_fill_points, replace=False)
        pts = pts[np.sort(keep)]
    maps = {scene.frames[i].name: scene.truth_dir / "depth" / f"{scene.frames[i].name}.npy" for i in tr}
    maps = {name: path for name, path in maps.items() if path.is_file()}  # the maps surface_samples read
    save_dense_depths(folder.out / "init" / FILE, list(maps), [np.load(path) for path in maps.values()])  # [h, w] m
    log(f"init: ORACLE: {len(pts)} points on the true surface, truth depth maps of {len(maps)} training views")
    return pts


if __name__ == "__main__":
    setup.dense_fill = truth_fill
    from brfgs.cli import main

    sys.exit(main(sys.argv[1:]))
