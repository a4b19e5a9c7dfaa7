"""COLMAP 4 (pycolmap) incremental and global mapping on timesift's verified matches, scored the
same way as timesift's own orientation. Used by `cargo xtask bench scale --colmap PYTHON`.

Usage: python colmap_scale.py INPUT PROJECT OUT.json --threads N

INPUT (written by the bench): images.csv (id, name, width, height, focal px, the initial
guesses timesift starts from), kp/<id>.f32 (N x 2 float32 keypoints, docs/design.md's pixel
convention, which COLMAP shares) and matches.bin (records of u32 a, u32 b, u32 count, then
count x 2 u32 keypoint indices: the verified inliers of timesift's match stage).

Every model (COLMAP incremental, COLMAP global, and timesift's own out/colmap) is scored alike:
georeferenced by a similarity to the GNSS priors (gnss.csv), and again by a similarity to the
GCPs intersected from their markers (the block's shape alone, without the GNSS biases); then
each check point is intersected per epoch from that epoch's markers and compared with
checkpoints.csv. RMSE (dE, dN, dH) in metres over every (epoch, check point).
"""
import argparse
import csv
import json
import os
import shutil
import sys
import time

import numpy as np
import pycolmap

pycolmap.logging.minloglevel = 2


def read_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def build_database(inp, db_path):
    images = read_rows(os.path.join(inp, "images.csv"))
    db = pycolmap.Database.open(db_path)
    ids = {}
    for row in images:
        w, h, f = int(row["width"]), int(row["height"]), float(row["focal_px"])
        cam = pycolmap.Camera.create_from_model_name(0, "OPENCV", f, w, h)
        cam.has_prior_focal_length = True
        cam_id = db.write_camera(cam)
        image_id = db.write_image(pycolmap.Image(name=row["name"], camera_id=cam_id))
        ids[int(row["id"])] = image_id
        kp = np.fromfile(os.path.join(inp, "kp", f"{row['id']}.f32"), dtype="<f4").reshape(-1, 2)
        db.write_keypoints(image_id, kp)
    raw = np.fromfile(os.path.join(inp, "matches.bin"), dtype="<u4")
    k, pairs = 0, 0
    while k < len(raw):
        a, b, n = raw[k], raw[k + 1], raw[k + 2]
        m = raw[k + 3:k + 3 + 2 * n].reshape(-1, 2).astype(np.uint32)
        k += 3 + 2 * n
        ia, ib = ids[int(a)], ids[int(b)]
        if ia > ib:
            ia, ib, m = ib, ia, m[:, ::-1].copy()
        db.write_matches(ia, ib, m)
        tvg = pycolmap.TwoViewGeometry()
        tvg.config = pycolmap.TwoViewGeometryConfiguration.UNCALIBRATED
        tvg.inlier_matches = m
        db.write_two_view_geometry(ia, ib, tvg)
        pairs += 1
    db.close()
    return len(images), pairs


def rays(rec):
    """name -> (centre, R world_from_cam, camera) of every image with a pose."""
    out = {}
    for im in rec.images.values():
        if not im.has_pose:
            continue
        pose = im.cam_from_world()
        out[im.name] = (np.asarray(im.projection_center()), pose.rotation.matrix().T,
                        rec.cameras[im.camera_id])
    return out


def intersect(observations, posed, transform=None):
    """Least-squares intersection of the rays of (image, u, v) observations; None below two."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    n = 0
    for name, u, v in observations:
        if name not in posed:
            continue
        c, r, cam = posed[name]
        xy = cam.cam_from_img(np.array([u, v]))
        if xy is None:
            continue
        d = r @ np.array([xy[0], xy[1], 1.0])
        if transform is not None:
            c = transform * c
            d = transform.rotation.matrix() @ d
        d /= np.linalg.norm(d)
        p = np.eye(3) - np.outer(d, d)
        a += p
        b += p @ c
        n += 1
    if n < 2:
        return None
    return np.linalg.solve(a, b)


def score(rec, project, epoch_of):
    posed = rays(rec)
    gnss = {r["image"]: np.array([float(r["x"]), float(r["y"]), float(r["z"])])
            for r in read_rows(os.path.join(project, "gnss.csv"))}
    markers = {}
    for r in read_rows(os.path.join(project, "markers.csv")):
        markers.setdefault(r["name"], []).append((r["image"], float(r["u"]), float(r["v"])))
    truth = {}
    for f in ("gcps.csv", "checkpoints.csv"):
        for r in read_rows(os.path.join(project, f)):
            truth[r["name"]] = np.array([float(r["x"]), float(r["y"]), float(r["z"])])
    origin = np.mean(list(gnss.values()), axis=0)
    result = {"registered": len(posed)}
    # Similarity to the GNSS priors of the posed images.
    names = [n for n in posed if n in gnss]
    src = np.array([posed[n][0] for n in names])
    dst = np.array([gnss[n] - origin for n in names])
    to_gnss = pycolmap.estimate_sim3d(src, dst)
    # Similarity to the GCPs intersected from all their markers.
    gcp_names = [r["name"] for r in read_rows(os.path.join(project, "gcps.csv"))]
    src, dst = [], []
    for n in gcp_names:
        x = intersect(markers.get(n, []), posed)
        if x is not None:
            src.append(x)
            dst.append(truth[n] - origin)
    to_gcps = pycolmap.estimate_sim3d(np.array(src), np.array(dst)) if len(src) >= 3 else None
    checks = [r["name"] for r in read_rows(os.path.join(project, "checkpoints.csv"))]
    for label, transform in (("gnss", to_gnss), ("gcps", to_gcps)):
        errors = []
        if transform is not None:
            for n in checks:
                by_epoch = {}
                for obs in markers.get(n, []):
                    by_epoch.setdefault(epoch_of.get(obs[0]), []).append(obs)
                for obs in by_epoch.values():
                    x = intersect(obs, posed, transform)
                    if x is not None:
                        errors.append(x - (truth[n] - origin))
        if errors:
            e = np.array(errors)
            result[f"check_rmse_{label}_m"] = list(np.sqrt((e ** 2).mean(axis=0)))
            result[f"checks_{label}"] = len(errors)
    return result


def largest(recs):
    if not recs:
        return None
    return max(recs.values(), key=lambda r: r.num_reg_images())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("input")
    ap.add_argument("project")
    ap.add_argument("out_json")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--skip-incremental", action="store_true")
    args = ap.parse_args()
    work = os.path.join(args.input, "colmap")
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    db_path = os.path.join(work, "database.db")
    t0 = time.time()
    n_images, n_pairs = build_database(args.input, db_path)
    epoch_of = {r["name"]: r["epoch"] for r in read_rows(os.path.join(args.input, "images.csv"))}
    rows = [{"mapper": "database", "seconds": time.time() - t0, "images": n_images,
             "pairs": n_pairs}]
    # timesift's own block, scored alike.
    ours = pycolmap.Reconstruction(os.path.join(args.project, "out", "colmap"))
    rows.append({"mapper": "timesift", "seconds": None, **score(ours, args.project, epoch_of)})
    images_dir = os.path.join(work, "no-images")
    os.makedirs(images_dir)
    mappers = []
    if not args.skip_incremental:
        inc = pycolmap.IncrementalPipelineOptions()
        inc.num_threads = args.threads
        inc.extract_colors = False
        inc.random_seed = 1
        mappers.append(("colmap-incremental",
                        lambda out: pycolmap.incremental_mapping(db_path, images_dir, out, options=inc)))
    glo = pycolmap.GlobalPipelineOptions()
    glo.num_threads = args.threads
    glo.random_seed = 1
    glo.mapper.global_positioning.use_gpu = False
    glo.mapper.bundle_adjustment.ceres.use_gpu = False
    mappers.append(("colmap-global",
                    lambda out: pycolmap.global_mapping(db_path, images_dir, out, options=glo)))
    for name, run in mappers:
        out = os.path.join(work, name)
        os.makedirs(out)
        t0 = time.time()
        try:
            rec = largest(run(out))
        except Exception as e:  # a peer's failure is a row, not the bench's end
            rows.append({"mapper": name, "seconds": time.time() - t0, "error": str(e)})
            continue
        seconds = time.time() - t0
        row = {"mapper": name, "seconds": seconds}
        if rec is None:
            row["error"] = "no model"
        else:
            row.update(score(rec, args.project, epoch_of))
        rows.append(row)
        print(f"{name}: {seconds:.1f} s, {row.get('registered', 0)} images", file=sys.stderr)
    with open(args.out_json, "w") as f:
        json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
