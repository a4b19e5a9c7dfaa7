#!/usr/bin/env python3
"""Reference M3C2 run with py4dgeo.

usage: python3 py4dgeo_m3c2.py EPOCH1 EPOCH2 CORE OUT.bin --normal-radius R
           --cyl-radius r --max-distance D --registration-error E [--threads N]
           [--robust] [--extra EXTRA.bin] [--include-tree-build]

Inputs: whitespace-separated text (x y z [ignored extra columns], '#' comments)
or .npy (float array of shape (n, >=3)); chosen by the file extension.
--normal-radius may be given several times (multi-scale normals).

OUT.bin:   little-endian f64, shape (n_core, 2): distance, lodetection
           (NaN where py4dgeo yields NaN).
EXTRA.bin: little-endian f64, shape (n_core, 9): distance, lodetection,
           spread1, num_samples1, spread2, num_samples2, nx, ny, nz
stdout:    one JSON line.
Timing: only the M3C2.run() call (which includes the normal computation).
KD-trees are built beforehand and timed separately as tree_seconds, unless
--include-tree-build is given (then run() builds them itself).
Threads: py4dgeo.set_num_threads(N) (= omp_set_num_threads in the C++ ext).
"""
import argparse
import json
import os
import sys
import time

import numpy as np


def load_points(path):
    if path.lower().endswith(".npy"):
        a = np.load(path)
    else:
        try:
            import pandas as pd

            a = pd.read_csv(path, sep=r"\s+", header=None, comment="#",
                            usecols=[0, 1, 2], dtype=np.float64).to_numpy()
        except ImportError:
            a = np.loadtxt(path, usecols=(0, 1, 2), dtype=np.float64, ndmin=2)
    a = np.ascontiguousarray(np.asarray(a, dtype=np.float64)[:, :3])
    return a


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("epoch1")
    ap.add_argument("epoch2")
    ap.add_argument("core")
    ap.add_argument("out")
    ap.add_argument("--normal-radius", type=float, action="append", required=True)
    ap.add_argument("--cyl-radius", type=float, required=True)
    ap.add_argument("--max-distance", type=float, required=True)
    ap.add_argument("--registration-error", type=float, default=0.0)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--robust", action="store_true", help="median/IQR aggregation")
    ap.add_argument("--extra", default=None)
    ap.add_argument("--include-tree-build", action="store_true")
    args = ap.parse_args()

    import logging
    import py4dgeo

    logging.getLogger("py4dgeo").setLevel(logging.WARNING)

    if args.threads is not None:
        py4dgeo.set_num_threads(args.threads)
    threads = py4dgeo.get_num_threads()

    p1 = load_points(args.epoch1)
    p2 = load_points(args.epoch2)
    core = load_points(args.core)

    e1 = py4dgeo.Epoch(p1)
    e2 = py4dgeo.Epoch(p2)

    tree_seconds = 0.0
    if not args.include_tree_build:
        t0 = time.perf_counter()
        e1.build_kdtree()  # leaf size 10, same as py4dgeo's lazy build
        e2.build_kdtree()
        tree_seconds = time.perf_counter() - t0

    m3c2 = py4dgeo.M3C2(
        epochs=(e1, e2),
        corepoints=core,
        normal_radii=list(args.normal_radius),
        cyl_radius=args.cyl_radius,
        max_distance=args.max_distance,
        registration_error=args.registration_error,
        robust_aggr=args.robust,
        orientation_vector=np.array([0.0, 0.0, 1.0]),
    )

    t0 = time.perf_counter()
    distances, unc = m3c2.run()
    seconds = time.perf_counter() - t0

    distances = np.asarray(distances, dtype=np.float64)
    lod = np.asarray(unc["lodetection"], dtype=np.float64)
    out = np.empty((core.shape[0], 2), dtype="<f8")
    out[:, 0] = distances
    out[:, 1] = lod
    out.tofile(args.out)

    if args.extra:
        normals = np.asarray(m3c2.corepoint_normals, dtype=np.float64)
        if normals.shape[0] == 1:
            normals = np.repeat(normals, core.shape[0], axis=0)
        ex = np.empty((core.shape[0], 9), dtype="<f8")
        ex[:, 0] = distances
        ex[:, 1] = lod
        ex[:, 2] = unc["spread1"]
        ex[:, 3] = unc["num_samples1"]
        ex[:, 4] = unc["spread2"]
        ex[:, 5] = unc["num_samples2"]
        ex[:, 6:9] = normals
        ex.tofile(args.extra)

    info = {
        "version": py4dgeo.__version__,
        "n_core": int(core.shape[0]),
        "n_epoch1": int(p1.shape[0]),
        "n_epoch2": int(p2.shape[0]),
        "seconds": seconds,
        "tree_seconds": tree_seconds,
        "threads": int(threads),
        "omp_num_threads_env": os.environ.get("OMP_NUM_THREADS"),
        "n_nan_distance": int(np.isnan(distances).sum()),
        "n_nan_lod": int(np.isnan(lod).sum()),
        "mean_distance": float(np.nanmean(distances)) if np.isfinite(distances).any() else None,
        "robust": bool(args.robust),
    }
    print(json.dumps(info))


if __name__ == "__main__":
    main()
